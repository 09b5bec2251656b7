//! Warm-up: two steps of a small synthetic scene through every model's scheduler before the
//! server reports ready (for PhysiFormer models: one denoising step of a two-frame sample of
//! one tetrahedron), so that the first request does not pay for lazy initialisation.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Instant;

use dynaserve_api::spec::{Mesh, Motion, ObjectSpec, Pose, Scene, Shape};

use super::Engine;
use super::registry::prepare_scenes;
use super::stepper::{Stepper, StepperSpec};
use crate::error::ApiError;
use crate::scheduler::Priority;
use crate::scheduler::denoise::{GenerateJob, generate};
use dynaserve_model::physiformer::flow::SamplerKind;
use dynaserve_model::physiformer::scene::{Material, MeshScene};

/// Steps run per model.
const STEPS: u32 = 2;

/// A unit cube at `(x, 0, z)`, at rest, sampled with `points` points.
fn cube(x: f32, z: f32, points: u32) -> ObjectSpec {
    let mesh = dynaserve_geometry::mesh::cube();
    ObjectSpec {
        shape: Shape::Mesh(Mesh {
            vertices: mesh.vertices,
            faces: mesh.faces,
            samples: points,
            seed: 1,
        }),
        pose: Pose {
            translation: [x, 0.0, z],
            ..Pose::IDENTITY
        },
        motion: Motion::Rest,
        mass: 1.0,
        friction: 0.5,
        restitution: 0.3,
    }
}

impl Engine {
    /// Runs `STEPS` steps of two cubes through every model's scheduler.
    pub async fn warm_up(&self) -> Result<(), ApiError> {
        for entry in self.models.values() {
            let start = Instant::now();
            let points = entry.limits.default_points.clamp(1, 256) as u32;
            let scene = Scene {
                objects: vec![cube(0.0, 0.5, points), cube(0.3, 1.6, points)],
            };
            let (scene, state) = prepare_scenes(entry, vec![scene], 1, "scene", Arc::from([]))
                .await
                .map_err(|e| ApiError::internal(format!("warm-up: {}", e.message)))?
                .scenes
                .pop()
                .ok_or_else(|| ApiError::internal("warm-up: no scene prepared"))?;
            let mut stepper = Stepper::new(
                Arc::clone(entry),
                StepperSpec {
                    scene,
                    state,
                    dt_steps: 1,
                    priority: Priority::Interactive,
                    deadline: None,
                    stream_id: self.next_stream.fetch_add(1, Ordering::Relaxed),
                    caller: 0,
                    request_id: crate::scheduler::WARMUP_REQUEST_ID.into(),
                },
            );
            for step in 1..=STEPS {
                stepper
                    .next(step < STEPS)
                    .await
                    .map_err(|e| ApiError::internal(format!("warm-up step: {}", e.message)))?;
            }
            tracing::info!(
                model = %entry.name,
                ms = start.elapsed().as_secs_f64() * 1e3,
                "warmed up"
            );
        }
        for entry in self.generators.values() {
            let start = Instant::now();
            let positions = vec![
                [0.0, 0.0, -0.9],
                [0.1, 0.0, -0.9],
                [0.0, 0.1, -0.9],
                [0.0, 0.0, -0.8],
            ];
            let scene = MeshScene {
                velocities: vec![[0.0; 3]; positions.len()],
                positions,
                vertex_offsets: vec![0, 4],
                materials: vec![Material::Elastic],
            };
            let job = GenerateJob {
                scene: Arc::new(scene),
                frames: 2,
                steps: 1,
                sampler: SamplerKind::Heun,
                seed: 0,
                noise: None,
                priority: Priority::Interactive,
                deadline: None,
                stream_id: self.next_stream.fetch_add(1, Ordering::Relaxed),
                caller: 0,
                request_id: crate::scheduler::WARMUP_REQUEST_ID.into(),
            };
            generate(&entry.scheduler, job, |_| {})
                .await
                .map_err(|e| ApiError::internal(format!("warm-up sample: {e}")))?;
            tracing::info!(
                model = %entry.name,
                ms = start.elapsed().as_secs_f64() * 1e3,
                "warmed up"
            );
        }
        Ok(())
    }
}
