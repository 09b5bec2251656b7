//! Warm-up: two steps of a small synthetic scene through every model's scheduler before the
//! server reports ready (for sampling models, what their family's warm-up runs), so that the
//! first request does not pay for lazy initialisation.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Instant;

use dynaserve_api::spec::{Mesh, Motion, ObjectSpec, Pose, Scene, Shape};

use super::Engine;
use super::registry::prepare_scenes;
use super::stepper::{Stepper, StepperSpec};
use crate::error::ApiError;
use crate::scheduler::Priority;

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
        for sampler in self.samplers.values() {
            let start = Instant::now();
            sampler.warm_up(self).await?;
            tracing::info!(
                model = %sampler.name(),
                ms = start.elapsed().as_secs_f64() * 1e3,
                "warmed up"
            );
        }
        Ok(())
    }
}
