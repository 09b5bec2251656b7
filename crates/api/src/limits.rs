//! Request limits, defined once: the server's caps (its flags, defaults in [`Caps::DEFAULT`]),
//! the model's own limits, and the fixed physical ranges every request must respect. The
//! extents and the largest step size are the model's constants (`dynaserve_model`); every
//! limit is reported by `ListModels` / `GET /v1/models`.

use dynaserve_model::ModelConfig;
use dynaserve_model::physiformer::config::PhysiConfig;
use dynaserve_model::physiformer::flow::MAX_STEPS as MAX_DENOISE_STEPS;
use dynaserve_model::physiformer::flow::SamplerKind;

pub use dynaserve_model::{MAX_BODY_EXTENT, MAX_DT_STEPS, MAX_WORLD_EXTENT};

/// Largest accepted linear speed component, m/s.
pub const MAX_SPEED: f32 = 1.0e3;
/// Largest accepted angular speed component, rad/s.
pub const MAX_ANGULAR_SPEED: f32 = 1.0e3;
/// Quaternions whose norm is within this of 1 are renormalised; others are rejected.
pub const QUATERNION_TOLERANCE: f32 = 1.0e-3;
/// Smallest accepted mass, kilograms (a milligram; lighter objects are below the model's
/// training range by orders of magnitude and only feed it denormal logarithms).
pub const MIN_MASS: f32 = 1.0e-6;
/// Fewest points of an object's cloud (or mesh samples): fewer cannot describe a shape.
pub const MIN_POINTS: usize = 4;
/// Largest accepted mass, kilograms.
pub const MAX_MASS: f32 = 1.0e4;
/// Largest accepted friction coefficient.
pub const MAX_FRICTION: f32 = 10.0;

/// Caps on requests. The server's flags are one `Caps` (defaults in [`Caps::DEFAULT`]); a
/// model's [`Limits`] hold the same caps lowered to what that model accepts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Caps {
    /// Objects per scene.
    pub max_objects: usize,
    /// Points (or mesh samples) per object.
    pub max_points_per_object: usize,
    /// Points per scene, summed over its objects.
    pub max_scene_points: usize,
    /// Steps per request.
    pub max_steps: u32,
    /// Frames per step.
    pub max_dt_steps: u32,
    /// Variants per Predict call.
    pub max_variants: usize,
    /// Cost of one request in object-steps ([`object_steps`]: objects x steps, summed over a
    /// Predict call's variants).
    pub max_request_cost: u64,
    /// Work of one Gradient call in scene-steps: candidates x steps. The backward pass keeps
    /// every step's activations of every candidate, so its memory grows with this.
    pub max_gradient_work: u64,
}

impl Caps {
    /// The defaults of `dynaserve serve`.
    pub const DEFAULT: Caps = Caps {
        max_objects: 256,
        max_points_per_object: 4096,
        max_scene_points: 131_072,
        max_steps: 10_000,
        max_dt_steps: 8,
        max_variants: 256,
        // About 4 minutes of a 2-core machine at ~4,000 object-steps/s (256-object scenes).
        max_request_cost: 1_000_000,
        // 48 candidates of 10 steps, with room: about 5 s and 2 GiB for a box and a pusher on
        // 2 cores (BENCHMARKS.md), and a pass holds the device that long.
        max_gradient_work: 512,
    };

    /// These caps lowered to the own limits of a model with configuration `model` (objects
    /// and points per object) and to the largest step size any model takes
    /// ([`MAX_DT_STEPS`]).
    pub fn for_model(&self, model: &ModelConfig) -> Caps {
        Caps {
            max_objects: self.max_objects.min(model.max_objects),
            max_points_per_object: self.max_points_per_object.min(model.max_points_per_object),
            max_dt_steps: self.max_dt_steps.min(MAX_DT_STEPS),
            ..*self
        }
    }
}

impl Default for Caps {
    fn default() -> Caps {
        Caps::DEFAULT
    }
}

/// Request limits for one model: the server's caps lowered to the model's own limits, and the
/// point count a mesh is sampled with when it names none.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// The caps in force for this model.
    pub caps: Caps,
    /// Points sampled from a mesh when `samples` is 0 (at most `caps.max_points_per_object`).
    pub default_points: usize,
}

impl Limits {
    /// Limits for a model with configuration `model` under the server caps `caps`.
    pub fn new(caps: &Caps, model: &ModelConfig) -> Limits {
        let caps = caps.for_model(model);
        Limits {
            caps,
            default_points: model.points_per_object.min(caps.max_points_per_object),
        }
    }
}

/// Caps on Generate requests (PhysiFormer models), set by the server's flags.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GenerateCaps {
    /// Denoising steps per request.
    pub max_denoise_steps: u32,
    /// Samples per request.
    pub max_samples: u32,
    /// Cost of one request in vertex-frame evaluations ([`vertex_frame_evaluations`]).
    pub max_cost: u64,
}

impl GenerateCaps {
    /// The defaults of `dynaserve serve`.
    pub const DEFAULT: GenerateCaps = GenerateCaps {
        max_denoise_steps: 200,
        max_samples: 16,
        // About 4.4 minutes of the bundled small model at ~61,000 vertex-frame evaluations/s
        // (2.5 samples/s of the 16-vertex, 49-frame, 31-evaluation example, BENCHMARKS.md).
        max_cost: 16_000_000,
    };
}

impl Default for GenerateCaps {
    fn default() -> GenerateCaps {
        GenerateCaps::DEFAULT
    }
}

/// Generate limits of one PhysiFormer model: the server's caps lowered to the model's own.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GenerateLimits {
    /// Objects per scene.
    pub max_objects: usize,
    /// Vertices per scene, summed over its objects.
    pub max_vertices: usize,
    /// Frames of a trajectory (frame 0 included); also the default.
    pub max_frames: u32,
    /// Denoising steps per request.
    pub max_denoise_steps: u32,
    /// Denoising steps of a request that names none.
    pub default_denoise_steps: u32,
    /// Samples per request.
    pub max_samples: u32,
    /// Cost of one request in vertex-frame evaluations ([`vertex_frame_evaluations`]).
    pub max_cost: u64,
    /// Half extent `e` of the model's box `[-e, e]^3`, metres; vertices must lie within `2e`.
    pub box_half_extent: f32,
    /// Interval between frames, seconds.
    pub dt_frame: f64,
}

impl GenerateLimits {
    /// Limits for a model with configuration `model` under the server's Generate caps and
    /// its per-scene object cap `max_objects`.
    pub fn new(caps: &GenerateCaps, max_objects: usize, model: &PhysiConfig) -> GenerateLimits {
        let max_denoise_steps = caps.max_denoise_steps.min(MAX_DENOISE_STEPS as u32).max(1);
        GenerateLimits {
            max_objects: max_objects.min(model.max_objects),
            max_vertices: model.max_vertices,
            max_frames: model.frames as u32,
            max_denoise_steps,
            default_denoise_steps: (model.default_steps as u32).clamp(1, max_denoise_steps),
            max_samples: caps.max_samples.max(1),
            max_cost: caps.max_cost.max(1),
            box_half_extent: model.box_half_extent,
            dt_frame: f64::from(model.dt_frame),
        }
    }
}

/// The cost of a RigidFormer request in object-steps: `steps` steps of every scene whose object
/// count `objects` yields (one scene for Rollout and a session's Step, one per variant for
/// Predict), i.e. the sum of objects x steps. Saturates at `u64::MAX`.
pub fn object_steps(objects: impl IntoIterator<Item = usize>, steps: u32) -> u64 {
    objects.into_iter().fold(0u64, |sum, n| {
        sum.saturating_add((n as u64).saturating_mul(u64::from(steps)))
    })
}

/// Network evaluations one Generate sample of `denoise_steps` steps takes: `2 steps - 1` with
/// the Heun sampler (two per interval, one in the last), `steps` with Euler.
pub fn network_evaluations(denoise_steps: u32, sampler: SamplerKind) -> u64 {
    let steps = u64::from(denoise_steps);
    match sampler {
        SamplerKind::Heun => (2 * steps).saturating_sub(1),
        SamplerKind::Euler => steps,
    }
}

/// The cost of a Generate request in vertex-frame evaluations: vertices x frames x network
/// evaluations per sample ([`network_evaluations`]) x samples. Saturates at `u64::MAX`.
pub fn vertex_frame_evaluations(
    vertices: usize,
    frames: usize,
    evaluations: u64,
    samples: u32,
) -> u64 {
    (vertices as u64)
        .saturating_mul(frames as u64)
        .saturating_mul(evaluations)
        .saturating_mul(u64::from(samples))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn object_steps_sum_each_scene_and_saturate() {
        assert_eq!(object_steps([256], 10_000), 2_560_000);
        assert_eq!(object_steps([256; 256], 10_000), 655_360_000);
        assert_eq!(object_steps([3, 5, 0], 7), 56);
        assert_eq!(object_steps(std::iter::empty(), 7), 0);
        assert_eq!(object_steps([usize::MAX], u32::MAX), u64::MAX);
        assert_eq!(object_steps([usize::MAX, usize::MAX], 1), u64::MAX);
    }

    #[test]
    fn heun_takes_two_evaluations_a_step_but_one_in_the_last() {
        assert_eq!(network_evaluations(1, SamplerKind::Heun), 1);
        assert_eq!(network_evaluations(50, SamplerKind::Heun), 99);
        assert_eq!(network_evaluations(50, SamplerKind::Euler), 50);
        assert_eq!(network_evaluations(0, SamplerKind::Heun), 0);
        assert_eq!(
            network_evaluations(u32::MAX, SamplerKind::Heun),
            2 * u64::from(u32::MAX) - 1
        );
    }

    #[test]
    fn vertex_frame_evaluations_multiply_and_saturate() {
        assert_eq!(vertex_frame_evaluations(16, 49, 99, 2), 16 * 49 * 99 * 2);
        assert_eq!(vertex_frame_evaluations(0, 49, 99, 2), 0);
        assert_eq!(
            vertex_frame_evaluations(usize::MAX, usize::MAX, u64::MAX, u32::MAX),
            u64::MAX
        );
    }

    #[test]
    fn the_cost_caps_survive_a_model_and_are_at_least_one() {
        let caps = Caps {
            max_request_cost: 1234,
            ..Caps::DEFAULT
        };
        assert_eq!(caps.for_model(&ModelConfig::tiny()).max_request_cost, 1234);
        let caps = GenerateCaps {
            max_cost: 0,
            ..GenerateCaps::DEFAULT
        };
        assert_eq!(
            GenerateLimits::new(&caps, 8, &PhysiConfig::small()).max_cost,
            1
        );
    }
}
