//! Conversions between the JSON documents ([`crate::json`]) and the generated gRPC messages
//! ([`crate::v1`]): what a client sends (JSON form -> gRPC) and receives (gRPC frames -> JSON
//! form) over gRPC. The server never takes this path: it maps each wire form to the neutral
//! vocabulary (`crate::spec`) directly.

use crate::json::{
    IDENTITY_ROTATION, ObjectSpec, Pose, PredictRequest, RolloutRequest, Scene, StepFrame,
    StepTiming,
};
use crate::v1;

pub(crate) fn vec3_from(v: Option<&v1::Vec3>) -> [f32; 3] {
    v.map_or([0.0; 3], |v| [v.x, v.y, v.z])
}

impl ObjectSpec {
    /// Converts to the gRPC form. If both `points` and `mesh` are set, `points` wins; if both
    /// `previous_pose` and `velocity` are set, `previous_pose` wins (the server rejects such a
    /// JSON object before converting).
    pub fn to_proto(&self) -> v1::ObjectSpec {
        let shape = match (&self.points, &self.mesh) {
            (Some(p), _) => Some(v1::object_spec::Shape::Points(v1::PointCloud {
                xyz: p.iter().flatten().copied().collect(),
            })),
            (None, Some(m)) => Some(v1::object_spec::Shape::Mesh(v1::TriangleMesh {
                vertices: m.vertices.iter().flatten().copied().collect(),
                faces: m.faces.iter().flatten().copied().collect(),
                samples: m.samples,
                seed: m.seed,
            })),
            (None, None) => None,
        };
        let motion = match (&self.previous_pose, &self.velocity) {
            (Some(p), _) => Some(v1::object_spec::Motion::PreviousPose(p.to_proto())),
            (None, Some(v)) => Some(v1::object_spec::Motion::Velocity(v1::Velocity {
                linear: Some(vec3_to(v.linear)),
                angular: Some(vec3_to(v.angular)),
            })),
            (None, None) => None,
        };
        v1::ObjectSpec {
            shape,
            pose: Some(self.pose.to_proto()),
            motion,
            mass: self.mass,
            friction: self.friction,
            restitution: self.restitution,
        }
    }
}

pub(crate) fn vec3_to(v: [f32; 3]) -> v1::Vec3 {
    v1::Vec3 {
        x: v[0],
        y: v[1],
        z: v[2],
    }
}

impl Pose {
    /// Converts to the gRPC form.
    pub fn to_proto(&self) -> v1::Pose {
        let [x, y, z, w] = self.rotation;
        v1::Pose {
            translation: Some(vec3_to(self.translation)),
            rotation: Some(v1::Quaternion { x, y, z, w }),
        }
    }

    /// Converts from the gRPC form (missing translation: origin; missing rotation: identity).
    pub fn from_proto(p: &v1::Pose) -> Pose {
        Pose {
            translation: vec3_from(p.translation.as_ref()),
            rotation: p
                .rotation
                .as_ref()
                .map_or(IDENTITY_ROTATION, |q| [q.x, q.y, q.z, q.w]),
        }
    }
}

impl Scene {
    /// Converts to the gRPC form.
    pub fn to_proto(&self) -> v1::Scene {
        v1::Scene {
            objects: self.objects.iter().map(ObjectSpec::to_proto).collect(),
        }
    }
}

impl RolloutRequest {
    /// Converts to the gRPC form (`stream` has no gRPC counterpart: gRPC always streams).
    pub fn to_proto(&self) -> v1::RolloutRequest {
        v1::RolloutRequest {
            model: self.model.clone(),
            scene: Some(self.scene.to_proto()),
            steps: self.steps,
            dt_steps: self.dt_steps,
            timeout_ms: self.timeout_ms,
        }
    }
}

impl PredictRequest {
    /// Converts to the gRPC form.
    pub fn to_proto(&self) -> v1::PredictRequest {
        v1::PredictRequest {
            model: self.model.clone(),
            variants: self.variants.iter().map(Scene::to_proto).collect(),
            steps: self.steps,
            dt_steps: self.dt_steps,
            every: self.every,
            timeout_ms: self.timeout_ms,
        }
    }
}

impl StepFrame {
    /// Converts from the gRPC form.
    pub fn from_proto(f: &v1::StepFrame) -> StepFrame {
        StepFrame {
            step: f.step,
            time: f.time,
            poses: f.poses.iter().map(Pose::from_proto).collect(),
            timing: f.timing.map(|t| StepTiming {
                queue_ms: t.queue_ms,
                forward_ms: t.forward_ms,
                batch_scenes: t.batch_scenes,
            }),
            spread: f
                .spread
                .iter()
                .map(|s| crate::json::ObjectSpread {
                    position_m: s.position_m,
                    orientation_deg: s.orientation_deg,
                })
                .collect(),
        }
    }
}

impl crate::json::GenerateRequest {
    /// Converts to the gRPC form (`stream` is HTTP only and has no gRPC field).
    pub fn to_proto(&self) -> v1::GenerateRequest {
        use crate::json::{Material, Sampler};
        let objects = self
            .scene
            .objects
            .iter()
            .map(|o| v1::MeshObject {
                vertices: o.vertices.iter().flatten().copied().collect(),
                faces: o.faces.iter().flatten().copied().collect(),
                material: match o.material {
                    Material::Rigid => v1::Material::Rigid,
                    Material::Elastic => v1::Material::Elastic,
                } as i32,
                velocity: o.velocity.map(|v| v1::Velocity {
                    linear: Some(vec3_to(v.linear)),
                    angular: Some(vec3_to(v.angular)),
                }),
                vertex_velocities: o
                    .vertex_velocities
                    .iter()
                    .flatten()
                    .flatten()
                    .copied()
                    .collect(),
            })
            .collect();
        v1::GenerateRequest {
            model: self.model.clone(),
            scene: Some(v1::MeshScene { objects }),
            frames: self.frames,
            denoise_steps: self.denoise_steps,
            sampler: match self.sampler {
                Sampler::Heun => v1::Sampler::Heun,
                Sampler::Euler => v1::Sampler::Euler,
            } as i32,
            samples: self.samples,
            seed: self.seed,
            timeout_ms: self.timeout_ms,
            raw_vertices: self.raw_vertices,
            noise: self.noise.iter().flatten().flatten().copied().collect(),
        }
    }
}

impl crate::json::GeneratedSample {
    /// Converts a received gRPC sample to the JSON form (a rigid object's pose and fit come
    /// together; an elastic object has neither).
    pub fn from_proto(s: &v1::GeneratedSample) -> crate::json::GeneratedSample {
        crate::json::GeneratedSample {
            sample: s.sample,
            seed: s.seed,
            frames: s
                .frames
                .iter()
                .map(|f| crate::json::MeshFrame {
                    frame: f.frame,
                    time: f.time,
                    objects: f
                        .objects
                        .iter()
                        .map(|o| crate::json::ObjectFrame {
                            vertices: o
                                .vertices
                                .chunks_exact(3)
                                .map(|c| [c[0], c[1], c[2]])
                                .collect(),
                            pose: o.pose.as_ref().map(Pose::from_proto),
                            fit_rms: o.pose.as_ref().map(|_| o.fit_rms),
                        })
                        .collect(),
                })
                .collect(),
        }
    }
}

impl crate::json::GenerateProgress {
    /// Converts a received gRPC progress event to the JSON form.
    pub fn from_proto(p: &v1::GenerateProgress) -> crate::json::GenerateProgress {
        let t = p.timing.unwrap_or_default();
        crate::json::GenerateProgress {
            step: p.step,
            steps: p.steps,
            t: p.t,
            timing: StepTiming {
                queue_ms: t.queue_ms,
                forward_ms: t.forward_ms,
                batch_scenes: t.batch_scenes,
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_defaults_and_unknown_fields() {
        let doc = r#"{"scene":{"objects":[{"points":[[0,0,0]],"pose":{"translation":[0,0,1]},"mass":1}]},"steps":3}"#;
        let r: RolloutRequest = serde_json::from_str(doc).unwrap();
        assert_eq!(r.scene.objects[0].pose.rotation, IDENTITY_ROTATION);
        assert_eq!(r.dt_steps, 0);
        let bad = r#"{"scene":{"objects":[]},"steps":3,"stepz":4}"#;
        assert!(serde_json::from_str::<RolloutRequest>(bad).is_err());
    }

    #[test]
    fn frames_come_back_from_the_grpc_form() {
        let f = v1::StepFrame {
            step: 3,
            time: 0.125,
            poses: vec![v1::Pose {
                translation: Some(vec3_to([1.0, 2.0, 3.0])),
                rotation: None,
            }],
            timing: Some(v1::StepTiming {
                queue_ms: 1.0,
                forward_ms: 2.0,
                batch_scenes: 4,
            }),
            spread: Vec::new(),
        };
        let j = StepFrame::from_proto(&f);
        assert_eq!(j.poses[0].translation, [1.0, 2.0, 3.0]);
        assert_eq!(j.poses[0].rotation, IDENTITY_ROTATION);
        assert_eq!(j.timing.unwrap().batch_scenes, 4);
    }
}
