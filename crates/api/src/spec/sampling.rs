//! The neutral form of Generate (PhysiFormer): a mesh scene in, denoising progress and sampled
//! trajectories out, with the conversions from and to both wire forms. Conversion checks only
//! the wire form's structure (whole triples, a material given); ranges and limits are checked
//! by the server's PhysiFormer family.

pub use dynaserve_model::physiformer::flow::SamplerKind;
pub use dynaserve_model::physiformer::scene::Material;

use super::v1::{pose_to_v1, triples};
use super::{Pose, StepTiming, millis};
use crate::error::FieldError;
use crate::json;
use crate::v1;
use crate::wire::vec3_from;

/// One object of a mesh scene at frame 0.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshObjectSpec {
    /// Vertex positions `[n, 3]` at frame 0, metres, world frame.
    pub vertices: Vec<[f32; 3]>,
    /// Triangles indexing `vertices` (checked, not used by the model).
    pub faces: Vec<[u32; 3]>,
    /// How it deforms.
    pub material: Material,
    /// Linear velocity of the vertex centroid, m/s.
    pub linear: [f32; 3],
    /// Angular velocity about the vertex centroid, rad/s (axis times rate).
    pub angular: [f32; 3],
    /// Per-vertex initial velocities `[n, 3]`, m/s, instead of `linear` and `angular`; empty
    /// when not given.
    pub vertex_velocities: Vec<[f32; 3]>,
}

/// A Generate request.
#[derive(Clone, Debug, PartialEq)]
pub struct GenerateSpec {
    /// Model name; empty when exactly one PhysiFormer model is resident.
    pub model: String,
    /// The scene's objects, in request order.
    pub objects: Vec<MeshObjectSpec>,
    /// Frames to sample (frame 0 included); 0 means the model's maximum.
    pub frames: u32,
    /// Denoising steps; 0 means the model's default.
    pub denoise_steps: u32,
    /// Integrator.
    pub sampler: SamplerKind,
    /// Samples; 0 means 1.
    pub samples: u32,
    /// Seed of the starting noise; sample `i` uses `seed + i`.
    pub seed: u64,
    /// Deadline in milliseconds from arrival; 0 means none.
    pub timeout_ms: u32,
    /// Rigid objects' vertices as sampled instead of moved by their fitted rigid motion.
    pub raw_vertices: bool,
    /// Starting noise per sample (standard-normal draws `[frames, V, 3]` flattened) instead
    /// of the seed; empty when not given.
    pub noise: Vec<Vec<f32>>,
}

/// One denoising step completed by every sample of a request.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GenerateProgress {
    /// Steps completed, from 1.
    pub step: u32,
    /// Steps in total.
    pub steps: u32,
    /// Flow time reached, `step / steps`.
    pub t: f32,
    /// Queue and forward time of the step's evaluations (slowest sample) and the widest pass.
    pub timing: StepTiming,
}

/// The rigid motion fitted to a rigid object's vertices at one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RigidFit {
    /// Pose of the body frame (frame-0 vertices about their centroid), world frame.
    pub pose: Pose,
    /// RMS distance of the vertices from the fitted motion, metres.
    pub rms: f32,
}

/// One object at one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectFrame {
    /// Vertex positions `[n, 3]`, metres, world frame (for a rigid object, its frame-0
    /// vertices moved by `fit` unless the request asked for the raw sample).
    pub vertices: Vec<[f32; 3]>,
    /// Rigid objects only: the rigid motion fitted to the sampled vertices.
    pub fit: Option<RigidFit>,
}

/// The scene at one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshFrame {
    /// Frame index, 0 for the given state.
    pub frame: u32,
    /// `frame * dt_frame`, seconds.
    pub time: f64,
    /// Every object, in request order.
    pub objects: Vec<ObjectFrame>,
}

/// One sampled trajectory.
#[derive(Clone, Debug, PartialEq)]
pub struct GeneratedSample {
    /// Sample index.
    pub sample: u32,
    /// Seed of its starting noise (not used when the request gives `noise`).
    pub seed: u64,
    /// Frames 0 to `frames - 1`.
    pub frames: Vec<MeshFrame>,
}

/// What a Generate call emits: progress per denoising step, then one sample each.
#[derive(Clone, Debug, PartialEq)]
pub enum GenerateEvent {
    /// A denoising step completed by every sample.
    Progress(GenerateProgress),
    /// A finished trajectory.
    Sample(GeneratedSample),
}

fn material_from_json(m: json::Material) -> Material {
    match m {
        json::Material::Rigid => Material::Rigid,
        json::Material::Elastic => Material::Elastic,
    }
}

impl GenerateSpec {
    /// Reads a `POST /v1/generate` body (its `stream` flag is the front end's business).
    pub fn from_json(r: &json::GenerateRequest) -> Result<GenerateSpec, FieldError> {
        let objects = r
            .scene
            .objects
            .iter()
            .map(|o| {
                let (linear, angular) = o
                    .velocity
                    .map_or(([0.0; 3], [0.0; 3]), |v| (v.linear, v.angular));
                MeshObjectSpec {
                    vertices: o.vertices.clone(),
                    faces: o.faces.clone(),
                    material: material_from_json(o.material),
                    linear,
                    angular,
                    vertex_velocities: o.vertex_velocities.clone().unwrap_or_default(),
                }
            })
            .collect();
        Ok(GenerateSpec {
            model: r.model.clone(),
            objects,
            frames: r.frames,
            denoise_steps: r.denoise_steps,
            sampler: match r.sampler {
                json::Sampler::Heun => SamplerKind::Heun,
                json::Sampler::Euler => SamplerKind::Euler,
            },
            samples: r.samples,
            seed: r.seed,
            timeout_ms: r.timeout_ms,
            raw_vertices: r.raw_vertices,
            noise: r.noise.clone().unwrap_or_default(),
        })
    }

    /// Reads a gRPC `Generate` request.
    pub fn from_v1(r: &v1::GenerateRequest) -> Result<GenerateSpec, FieldError> {
        let scene = r
            .scene
            .as_ref()
            .ok_or_else(|| FieldError::new("scene", "required"))?;
        let objects = scene
            .objects
            .iter()
            .enumerate()
            .map(|(i, o)| {
                let field = format!("scene.objects[{i}]");
                let material = match v1::Material::try_from(o.material) {
                    Ok(v1::Material::Rigid) => Material::Rigid,
                    Ok(v1::Material::Elastic) => Material::Elastic,
                    _ => {
                        return Err(FieldError::new(
                            format!("{field}.material"),
                            "required: MATERIAL_RIGID or MATERIAL_ELASTIC",
                        ));
                    }
                };
                let v = o.velocity.as_ref();
                Ok(MeshObjectSpec {
                    vertices: triples(&o.vertices, &format!("{field}.vertices"))?,
                    faces: triples(&o.faces, &format!("{field}.faces"))?,
                    material,
                    linear: vec3_from(v.and_then(|v| v.linear.as_ref())),
                    angular: vec3_from(v.and_then(|v| v.angular.as_ref())),
                    vertex_velocities: triples(
                        &o.vertex_velocities,
                        &format!("{field}.vertex_velocities"),
                    )?,
                })
            })
            .collect::<Result<_, _>>()?;
        let sampler = match v1::Sampler::try_from(r.sampler) {
            Ok(v1::Sampler::Unspecified | v1::Sampler::Heun) => SamplerKind::Heun,
            Ok(v1::Sampler::Euler) => SamplerKind::Euler,
            Err(_) => {
                return Err(FieldError::new(
                    "sampler",
                    format!("unknown sampler {}", r.sampler),
                ));
            }
        };
        Ok(GenerateSpec {
            model: r.model.clone(),
            objects,
            frames: r.frames,
            denoise_steps: r.denoise_steps,
            sampler,
            samples: r.samples,
            seed: r.seed,
            timeout_ms: r.timeout_ms,
            raw_vertices: r.raw_vertices,
            noise: split_noise(&r.noise, r.samples.max(1))?,
        })
    }
}

/// The flattened gRPC `noise` split into one list per sample (empty when not given).
fn split_noise(noise: &[f32], samples: u32) -> Result<Vec<Vec<f32>>, FieldError> {
    if noise.is_empty() {
        return Ok(Vec::new());
    }
    let s = samples as usize;
    if !noise.len().is_multiple_of(s) {
        return Err(FieldError::new(
            "noise",
            format!(
                "{} values do not split into {s} samples of equal length",
                noise.len()
            ),
        ));
    }
    Ok(noise.chunks(noise.len() / s).map(<[f32]>::to_vec).collect())
}

fn timing_json(t: &StepTiming) -> json::StepTiming {
    json::StepTiming {
        queue_ms: millis(t.queue) as f32,
        forward_ms: millis(t.forward) as f32,
        batch_scenes: t.batch_scenes,
    }
}

impl GenerateProgress {
    /// The JSON form (an SSE `progress` event).
    pub fn to_json(&self) -> json::GenerateProgress {
        json::GenerateProgress {
            step: self.step,
            steps: self.steps,
            t: self.t,
            timing: timing_json(&self.timing),
        }
    }

    /// The gRPC form.
    pub fn to_v1(&self) -> v1::GenerateProgress {
        let t = timing_json(&self.timing);
        v1::GenerateProgress {
            step: self.step,
            steps: self.steps,
            t: self.t,
            timing: Some(v1::StepTiming {
                queue_ms: t.queue_ms,
                forward_ms: t.forward_ms,
                batch_scenes: t.batch_scenes,
            }),
        }
    }
}

impl GeneratedSample {
    /// The JSON form (an SSE `sample` event, an element of a response).
    pub fn to_json(&self) -> json::GeneratedSample {
        json::GeneratedSample {
            sample: self.sample,
            seed: self.seed,
            frames: self
                .frames
                .iter()
                .map(|f| json::MeshFrame {
                    frame: f.frame,
                    time: f.time,
                    objects: f
                        .objects
                        .iter()
                        .map(|o| json::ObjectFrame {
                            vertices: o.vertices.clone(),
                            pose: o.fit.map(|fit| json::Pose {
                                translation: fit.pose.translation,
                                rotation: fit.pose.rotation,
                            }),
                            fit_rms: o.fit.map(|fit| fit.rms),
                        })
                        .collect(),
                })
                .collect(),
        }
    }

    /// The gRPC form.
    pub fn to_v1(&self) -> v1::GeneratedSample {
        v1::GeneratedSample {
            sample: self.sample,
            seed: self.seed,
            frames: self
                .frames
                .iter()
                .map(|f| v1::MeshFrame {
                    frame: f.frame,
                    time: f.time,
                    objects: f
                        .objects
                        .iter()
                        .map(|o| v1::ObjectFrame {
                            vertices: o.vertices.iter().flatten().copied().collect(),
                            pose: o.fit.map(|fit| pose_to_v1(&fit.pose)),
                            fit_rms: o.fit.map_or(0.0, |fit| fit.rms),
                        })
                        .collect(),
                })
                .collect(),
        }
    }
}

impl GenerateEvent {
    /// The gRPC stream message.
    pub fn to_v1(&self) -> v1::GenerateEvent {
        let event = match self {
            GenerateEvent::Progress(p) => v1::generate_event::Event::Progress(p.to_v1()),
            GenerateEvent::Sample(s) => v1::generate_event::Event::Sample(s.to_v1()),
        };
        v1::GenerateEvent { event: Some(event) }
    }
}

/// The Generate fields of a wire `ModelInfo`, in proto field order: `max_vertices`,
/// `max_frames`, `max_denoise_steps`, `default_denoise_steps`, `max_samples`.
pub(super) fn generate_fields(l: &crate::limits::GenerateLimits) -> [u32; 5] {
    [
        l.max_vertices as u32,
        l.max_frames,
        l.max_denoise_steps,
        l.default_denoise_steps,
        l.max_samples,
    ]
}
