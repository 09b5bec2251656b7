//! Generate requests: a neutral request checked into the model's [`MeshScene`] and sampling
//! parameters, with errors naming the field, and its cost against the server's
//! `--max-generate-cost`.
//!
//! Rules (limits in [`GenerateLimits`], reported by `ListModels`):
//! - 1..=`max_objects` objects, each with at least one vertex, `max_vertices` in all;
//! - every vertex coordinate finite and within `±2e` metres (`e`: the box half extent);
//! - faces index the object's own vertices;
//! - velocities finite, and every vertex's initial speed (`linear + angular x (x - c)`) at
//!   most [`MAX_SPEED`] m/s per component;
//! - `frames` 0 (the maximum) or 2..=`max_frames`; `denoise_steps` 0 (the default) or
//!   1..=`max_denoise_steps`; `samples` 0 (one) or 1..=`max_samples`;
//! - vertices x frames x network evaluations x samples at most `max_cost` vertex-frame
//!   evaluations ([`check_generate_cost`], named `denoise_steps`).

use dynaserve_api::FieldError;
use dynaserve_api::limits::{GenerateLimits, network_evaluations, vertex_frame_evaluations};
use dynaserve_api::spec::sampling::{GenerateSpec, MeshObjectSpec, SamplerKind};
use dynaserve_model::physiformer::scene::{MAX_SPEED, MeshScene};

use crate::error::count;

/// The sampling parameters of a checked request, defaults applied.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GenerateParams {
    /// Frames to sample, frame 0 included.
    pub frames: usize,
    /// Denoising steps.
    pub steps: usize,
    /// Samples.
    pub samples: u32,
    /// Report rigid objects' vertices as sampled instead of moved by their fitted motion.
    pub raw_vertices: bool,
}

/// Checks `frames`, `denoise_steps` and `samples` of `spec` and applies their defaults.
pub fn check_generate(
    spec: &GenerateSpec,
    limits: &GenerateLimits,
) -> Result<GenerateParams, FieldError> {
    let frames = if spec.frames == 0 {
        limits.max_frames
    } else {
        spec.frames
    };
    if frames < 2 || frames > limits.max_frames {
        return Err(FieldError::new(
            "frames",
            format!(
                "{} is outside 2..={} (frame 0 included; 0 means {})",
                spec.frames, limits.max_frames, limits.max_frames
            ),
        ));
    }
    let steps = if spec.denoise_steps == 0 {
        limits.default_denoise_steps
    } else {
        spec.denoise_steps
    };
    if steps > limits.max_denoise_steps {
        return Err(FieldError::new(
            "denoise_steps",
            format!(
                "{steps} is outside 1..={} (0 means {})",
                limits.max_denoise_steps, limits.default_denoise_steps
            ),
        ));
    }
    let samples = spec.samples.max(1);
    if samples > limits.max_samples {
        return Err(FieldError::new(
            "samples",
            format!("{samples} is outside 1..={}", limits.max_samples),
        ));
    }
    if !spec.noise.is_empty() {
        if spec.noise.len() != samples as usize {
            return Err(FieldError::new(
                "noise",
                format!(
                    "{} noise lists for {samples} samples (one per sample)",
                    spec.noise.len()
                ),
            ));
        }
        let vertices: usize = spec.objects.iter().map(|o| o.vertices.len()).sum();
        let want = frames as usize * vertices * 3;
        for (i, n) in spec.noise.iter().enumerate() {
            if n.len() != want {
                return Err(FieldError::new(
                    format!("noise[{i}]"),
                    format!(
                        "{} values; {frames} frames of {vertices} vertices need {want}",
                        n.len()
                    ),
                ));
            }
            if let Some(k) = n.iter().position(|x| !x.is_finite()) {
                return Err(FieldError::new(
                    format!("noise[{i}][{k}]"),
                    "must be finite (NaN or infinity given)",
                ));
            }
        }
    }
    Ok(GenerateParams {
        frames: frames as usize,
        steps: steps as usize,
        samples,
        raw_vertices: spec.raw_vertices,
    })
}

/// Checks the cost of a checked Generate request, `params` with the `sampler` given, on a scene
/// of `vertices` vertices, against the server's `--max-generate-cost`: vertices x frames x
/// network evaluations per sample x samples ([`vertex_frame_evaluations`]). Above the limit:
/// an error naming `denoise_steps` whose message names every factor and the flag. Returns the
/// cost.
pub fn check_generate_cost(
    params: &GenerateParams,
    sampler: SamplerKind,
    vertices: usize,
    limits: &GenerateLimits,
) -> Result<u64, FieldError> {
    let steps = u32::try_from(params.steps).unwrap_or(u32::MAX);
    let evaluations = network_evaluations(steps, sampler);
    let cost = vertex_frame_evaluations(vertices, params.frames, evaluations, params.samples);
    if cost <= limits.max_cost {
        return Ok(cost);
    }
    let how = match sampler {
        SamplerKind::Heun => format!(
            "Heun: 2 x {} - 1",
            count(u64::from(steps), "denoise step", "denoise steps")
        ),
        SamplerKind::Euler => "Euler: one per denoise step".to_string(),
    };
    Err(FieldError::new(
        "denoise_steps",
        format!(
            "{} x {} x {} ({how}) x {} = {cost} vertex-frame evaluations exceeds the server's \
             limit of {} (--max-generate-cost); lower denoise_steps, frames, samples or vertices",
            count(vertices as u64, "vertex", "vertices"),
            count(params.frames as u64, "frame", "frames"),
            count(evaluations, "network evaluation", "network evaluations"),
            count(u64::from(params.samples), "sample", "samples"),
            limits.max_cost
        ),
    ))
}

fn finite_triple(v: &[f32; 3], field: &str) -> Result<(), FieldError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(FieldError::new(
            field,
            "must be finite (NaN or infinity given)",
        ))
    }
}

fn centroid(points: &[[f32; 3]]) -> [f32; 3] {
    let mut c = [0f64; 3];
    for p in points {
        for k in 0..3 {
            c[k] += f64::from(p[k]);
        }
    }
    c.map(|v| (v / points.len().max(1) as f64) as f32)
}

fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Validates the objects of a Generate request (see the module docs) and builds the model's
/// scene: vertices in request order, each with its object's initial velocity field.
pub fn build_mesh_scene(
    objects: &[MeshObjectSpec],
    limits: &GenerateLimits,
) -> Result<MeshScene, FieldError> {
    if objects.is_empty() || objects.len() > limits.max_objects {
        return Err(FieldError::new(
            "scene.objects",
            format!(
                "{} objects given; 1..={} accepted",
                objects.len(),
                limits.max_objects
            ),
        ));
    }
    let total: usize = objects.iter().map(|o| o.vertices.len()).sum();
    if total > limits.max_vertices {
        return Err(FieldError::new(
            "scene.objects",
            format!(
                "{total} vertices in all exceed the model's limit of {}",
                limits.max_vertices
            ),
        ));
    }
    let bound = 2.0 * limits.box_half_extent;
    let mut scene = MeshScene {
        positions: Vec::with_capacity(total),
        velocities: Vec::with_capacity(total),
        vertex_offsets: vec![0],
        materials: Vec::with_capacity(objects.len()),
    };
    for (i, o) in objects.iter().enumerate() {
        let field = format!("scene.objects[{i}]");
        if o.vertices.is_empty() {
            return Err(FieldError::new(
                format!("{field}.vertices"),
                "at least one vertex is required",
            ));
        }
        for (k, v) in o.vertices.iter().enumerate() {
            let vf = format!("{field}.vertices[{k}]");
            finite_triple(v, &vf)?;
            if v.iter().any(|c| c.abs() > bound) {
                return Err(FieldError::new(
                    vf,
                    format!(
                        "{v:?} lies outside [-{bound}, {bound}]^3 m (the model's box is \
                         [-{e}, {e}]^3)",
                        e = limits.box_half_extent
                    ),
                ));
            }
        }
        let n = o.vertices.len() as u32;
        if let Some(k) = o.faces.iter().position(|f| f.iter().any(|&x| x >= n)) {
            return Err(FieldError::new(
                format!("{field}.faces[{k}]"),
                format!("{:?} indexes past the object's {n} vertices", o.faces[k]),
            ));
        }
        finite_triple(&o.linear, &format!("{field}.velocity.linear"))?;
        finite_triple(&o.angular, &format!("{field}.velocity.angular"))?;
        let per_vertex = !o.vertex_velocities.is_empty();
        if per_vertex && (o.linear != [0.0; 3] || o.angular != [0.0; 3]) {
            return Err(FieldError::new(
                format!("{field}.vertex_velocities"),
                "give either velocity or vertex_velocities, not both",
            ));
        }
        if per_vertex && o.vertex_velocities.len() != o.vertices.len() {
            return Err(FieldError::new(
                format!("{field}.vertex_velocities"),
                format!(
                    "{} velocities for {} vertices",
                    o.vertex_velocities.len(),
                    o.vertices.len()
                ),
            ));
        }
        let c = centroid(&o.vertices);
        for (k, v) in o.vertices.iter().enumerate() {
            let (u, vf) = if per_vertex {
                (
                    o.vertex_velocities[k],
                    format!("{field}.vertex_velocities[{k}]"),
                )
            } else {
                let r = [v[0] - c[0], v[1] - c[1], v[2] - c[2]];
                let w = cross(o.angular, r);
                (
                    [o.linear[0] + w[0], o.linear[1] + w[1], o.linear[2] + w[2]],
                    format!("{field}.velocity"),
                )
            };
            if u.iter().any(|x| !x.is_finite() || x.abs() > MAX_SPEED) {
                return Err(FieldError::new(
                    vf,
                    format!(
                        "gives a vertex the initial velocity {u:?} m/s; the model accepts at \
                         most {MAX_SPEED} m/s per component"
                    ),
                ));
            }
            scene.positions.push(*v);
            scene.velocities.push(u);
        }
        scene.vertex_offsets.push(scene.positions.len());
        scene.materials.push(o.material);
    }
    Ok(scene)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use dynaserve_api::limits::GenerateCaps;
    use dynaserve_model::physiformer::config::PhysiConfig;
    use dynaserve_model::physiformer::scene::Material;

    /// A 0.2 m cube of `material` centred at `c` (metres), moving at 1 m/s along x and
    /// turning at 2 rad/s about z.
    pub(crate) fn cube(c: [f32; 3], material: Material) -> MeshObjectSpec {
        let mut vertices = Vec::new();
        for i in 0..8 {
            let s = |b: usize| if i >> b & 1 == 1 { 0.1 } else { -0.1 };
            vertices.push([c[0] + s(0), c[1] + s(1), c[2] + s(2)]);
        }
        MeshObjectSpec {
            vertices,
            faces: vec![[0, 1, 3]],
            material,
            linear: [1.0, 0.0, 0.0],
            angular: [0.0, 0.0, 2.0],
            vertex_velocities: Vec::new(),
        }
    }

    fn spec(objects: Vec<MeshObjectSpec>) -> GenerateSpec {
        GenerateSpec {
            model: String::new(),
            objects,
            frames: 0,
            denoise_steps: 0,
            sampler: SamplerKind::Heun,
            samples: 0,
            seed: 0,
            timeout_ms: 0,
            raw_vertices: false,
            noise: Vec::new(),
        }
    }

    /// The default Generate limits of the small PhysiFormer with 256 objects.
    pub(crate) fn limits() -> GenerateLimits {
        GenerateLimits::new(&GenerateCaps::DEFAULT, 256, &PhysiConfig::small())
    }

    #[test]
    fn defaults_apply_and_limits_name_the_field() {
        let l = limits();
        let p = check_generate(&spec(vec![]), &l).unwrap();
        assert_eq!((p.frames, p.steps, p.samples), (49, 50, 1));
        let mut s = spec(vec![]);
        s.frames = 1;
        assert_eq!(check_generate(&s, &l).unwrap_err().field, "frames");
        s.frames = 4;
        s.denoise_steps = 100_000;
        assert_eq!(check_generate(&s, &l).unwrap_err().field, "denoise_steps");
        s.denoise_steps = 2;
        s.samples = 1000;
        assert_eq!(check_generate(&s, &l).unwrap_err().field, "samples");
    }

    #[test]
    fn generate_cost_names_every_factor_and_the_flag() {
        let mut l = limits();
        l.max_cost = 16 * 49 * 99 * 2;
        let mut s = spec(vec![]);
        s.denoise_steps = 50;
        s.samples = 2;
        let p = check_generate(&s, &l).unwrap();
        assert_eq!(
            check_generate_cost(&p, SamplerKind::Heun, 16, &l),
            Ok(l.max_cost)
        );
        // Euler takes half the evaluations (and one more step still fits).
        assert_eq!(
            check_generate_cost(&p, SamplerKind::Euler, 16, &l),
            Ok(16 * 49 * 50 * 2)
        );
        let e = check_generate_cost(&p, SamplerKind::Heun, 17, &l).unwrap_err();
        assert_eq!(e.field, "denoise_steps");
        assert_eq!(
            e.message,
            "17 vertices x 49 frames x 99 network evaluations (Heun: 2 x 50 denoise steps - 1) \
             x 2 samples = 164934 vertex-frame evaluations exceeds the server's limit of 155232 \
             (--max-generate-cost); lower denoise_steps, frames, samples or vertices"
        );
        s.denoise_steps = 100;
        let p = check_generate(&s, &l).unwrap();
        let e = check_generate_cost(&p, SamplerKind::Euler, 16, &l).unwrap_err();
        assert!(
            e.message.starts_with(
                "16 vertices x 49 frames x 100 network evaluations (Euler: one per denoise step) \
                 x 2 samples = 156800 vertex-frame evaluations"
            ),
            "{}",
            e.message
        );
    }

    #[test]
    fn scene_builds_with_velocity_fields_and_bad_input_names_the_field() {
        let l = limits();
        let objects = vec![
            cube([0.0, 0.0, -0.8], Material::Rigid),
            cube([0.5, 0.0, 0.0], Material::Elastic),
        ];
        let scene = build_mesh_scene(&objects, &l).unwrap();
        assert_eq!(scene.vertex_offsets, vec![0, 8, 16]);
        assert_eq!(scene.materials, vec![Material::Rigid, Material::Elastic]);
        // Vertex 0 sits at (-0.1, -0.1) from the centroid: w x r = (0.2, -0.2, 0).
        let u = scene.velocities[0];
        assert!(
            (u[0] - 1.2).abs() < 1e-6 && (u[1] + 0.2).abs() < 1e-6,
            "{u:?}"
        );
        assert!(scene.validate(&PhysiConfig::small()).is_ok());

        let mut bad = objects.clone();
        bad[1].vertices[3][2] = f32::NAN;
        let e = build_mesh_scene(&bad, &l).unwrap_err();
        assert_eq!(e.field, "scene.objects[1].vertices[3]");
        let mut bad = objects.clone();
        bad[0].vertices[0][0] = 5.0;
        let e = build_mesh_scene(&bad, &l).unwrap_err();
        assert_eq!(e.field, "scene.objects[0].vertices[0]");
        let mut bad = objects.clone();
        bad[1].faces = vec![[0, 1, 2], [0, 1, 8]];
        assert_eq!(
            build_mesh_scene(&bad, &l).unwrap_err().field,
            "scene.objects[1].faces[1]"
        );
        let mut bad = objects.clone();
        bad[0].linear = [100.0, 0.0, 0.0];
        assert_eq!(
            build_mesh_scene(&bad, &l).unwrap_err().field,
            "scene.objects[0].velocity"
        );
        let mut bad = objects.clone();
        bad[0].vertices.clear();
        assert_eq!(
            build_mesh_scene(&bad, &l).unwrap_err().field,
            "scene.objects[0].vertices"
        );
        assert_eq!(
            build_mesh_scene(&[], &l).unwrap_err().field,
            "scene.objects"
        );
        let big: Vec<MeshObjectSpec> = (0..65)
            .map(|i| cube([0.0, 0.0, -0.9 + 0.02 * i as f32], Material::Rigid))
            .collect();
        assert_eq!(
            build_mesh_scene(&big, &l).unwrap_err().field,
            "scene.objects"
        );
    }
}
