//! A sampled trajectory split back into per-object frames, with the rigid motion fitted
//! (Kabsch) to each rigid object and, unless the request asked for the raw sample, its
//! vertices moved exactly rigidly by it.

use dynaserve_api::spec::sampling::{MeshFrame, ObjectFrame, RigidFit};
use dynaserve_model::physiformer::rigid::fit_rigid;
use dynaserve_model::physiformer::scene::{Material, MeshScene};

/// A rigid object at one frame as reported: the rigid motion [`fit_rigid`] finds from its
/// frame-0 vertices `reference` to the sampled `vertices`, and, unless `raw`, the vertices
/// replaced by `reference` moved by that motion. No fit (and the vertices as sampled) when the
/// fit fails (non-finite points).
fn rigid_frame(reference: &[[f32; 3]], vertices: Vec<[f32; 3]>, raw: bool) -> ObjectFrame {
    let Ok(fit) = fit_rigid(reference, &vertices) else {
        return ObjectFrame {
            vertices,
            fit: None,
        };
    };
    let Ok(pose) = fit.pose() else {
        return ObjectFrame {
            vertices,
            fit: None,
        };
    };
    let vertices = if raw {
        vertices
    } else {
        reference.iter().map(|&p| fit.apply(p)).collect()
    };
    ObjectFrame {
        vertices,
        fit: Some(RigidFit {
            pose,
            rms: fit.rms as f32,
        }),
    }
}

/// Splits a sampled trajectory `[frames, V, 3]` (flattened, metres) of `scene` into frames of
/// per-object vertices, `dt_frame` seconds apart, with the rigid motion fitted to every rigid
/// object. Unless `raw_vertices`, a rigid object's vertices after frame 0 become its frame-0
/// vertices moved by that motion (exactly rigid); elastic objects are reported as sampled.
pub fn mesh_frames(
    scene: &MeshScene,
    trajectory: &[f32],
    frames: usize,
    dt_frame: f64,
    raw_vertices: bool,
) -> Vec<MeshFrame> {
    let nv = scene.vertices();
    (0..frames)
        .map(|f| {
            let at = &trajectory[f * nv * 3..(f + 1) * nv * 3];
            let objects = (0..scene.objects())
                .map(|o| {
                    let (s, e) = (scene.vertex_offsets[o], scene.vertex_offsets[o + 1]);
                    let vertices: Vec<[f32; 3]> = at[s * 3..e * 3]
                        .chunks_exact(3)
                        .map(|c| [c[0], c[1], c[2]])
                        .collect();
                    if scene.materials[o] == Material::Rigid {
                        // Frame 0 is the given state: reported exactly as given.
                        rigid_frame(&scene.positions[s..e], vertices, raw_vertices || f == 0)
                    } else {
                        ObjectFrame {
                            vertices,
                            fit: None,
                        }
                    }
                })
                .collect();
            MeshFrame {
                frame: f as u32,
                time: f as f64 * dt_frame,
                objects,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::families::physiformer::mesh_scene::build_mesh_scene;
    use crate::families::physiformer::mesh_scene::tests::{cube, limits};

    #[test]
    fn rigid_objects_get_their_exact_motion_back() {
        let l = limits();
        let objects = vec![
            cube([0.0, 0.0, 0.0], Material::Rigid),
            cube([0.5, 0.0, 0.0], Material::Elastic),
        ];
        let scene = build_mesh_scene(&objects, &l).unwrap();
        // Frame 1: the rigid cube turned 90 degrees about z and moved by (0.1, 0.2, 0.3).
        let mut traj: Vec<f32> = scene.positions.iter().flatten().copied().collect();
        for p in &scene.positions[..8] {
            traj.extend([-p[1] + 0.1, p[0] + 0.2, p[2] + 0.3]);
        }
        for p in &scene.positions[8..] {
            traj.extend([p[0] * 1.1, p[1], p[2]]);
        }
        let frames = mesh_frames(&scene, &traj, 2, 0.5, true);
        assert_eq!(frames[1].time, 0.5);
        let fit0 = frames[0].objects[0].fit.unwrap();
        assert!(fit0.rms < 1e-6 && (fit0.pose.rotation[3] - 1.0).abs() < 1e-6);
        let fit = frames[1].objects[0].fit.unwrap();
        assert!(fit.rms < 1e-5, "{}", fit.rms);
        let t = fit.pose.translation;
        assert!(
            (t[0] - 0.1).abs() < 1e-5 && (t[1] - 0.2).abs() < 1e-5 && (t[2] - 0.3).abs() < 1e-5
        );
        let s = std::f32::consts::FRAC_1_SQRT_2;
        let q = fit.pose.rotation;
        assert!((q[2] - s).abs() < 1e-5 && (q[3] - s).abs() < 1e-5, "{q:?}");
        assert!(frames[1].objects[1].fit.is_none());
        assert_eq!(
            frames[1].objects[1].vertices[0][0],
            scene.positions[8][0] * 1.1
        );
    }

    #[test]
    fn rigid_objects_are_reported_rigid_unless_raw_is_asked() {
        let l = limits();
        let objects = vec![
            cube([0.0, 0.0, 0.0], Material::Rigid),
            cube([0.5, 0.0, 0.0], Material::Elastic),
        ];
        let scene = build_mesh_scene(&objects, &l).unwrap();
        // Frame 1: the rigid cube shifted by (0.1, 0, 0) with one vertex pulled 3 cm off its
        // rigid place; the elastic cube stretched.
        let mut traj: Vec<f32> = scene.positions.iter().flatten().copied().collect();
        for (k, p) in scene.positions[..8].iter().enumerate() {
            let dz = if k == 5 { 0.03 } else { 0.0 };
            traj.extend([p[0] + 0.1, p[1], p[2] + dz]);
        }
        for p in &scene.positions[8..] {
            traj.extend([p[0] * 1.1, p[1], p[2]]);
        }
        let dist = |a: [f32; 3], b: [f32; 3]| {
            ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
        };
        let projected = mesh_frames(&scene, &traj, 2, 0.5, false);
        let raw = mesh_frames(&scene, &traj, 2, 0.5, true);
        let (p, r) = (&projected[1].objects[0], &raw[1].objects[0]);
        // Same fit either way, and it reports how far the sample was from rigid.
        assert_eq!(p.fit, r.fit);
        let rms = p.fit.unwrap().rms;
        assert!(rms > 0.005 && rms < 0.03, "{rms}");
        // Projected: every pairwise distance of frame 0 is kept.
        let v0 = &scene.positions[..8];
        for i in 0..8 {
            for j in 0..8 {
                let d = dist(p.vertices[i], p.vertices[j]) - dist(v0[i], v0[j]);
                assert!(d.abs() < 1e-5, "pair {i} {j}: {d}");
            }
        }
        // Raw: the pulled vertex is where the sample put it.
        assert_eq!(r.vertices[5][2], traj[(16 + 5) * 3 + 2]);
        assert!(dist(p.vertices[5], r.vertices[5]) > 0.01);
        // Elastic objects are never projected.
        assert_eq!(projected[1].objects[1], raw[1].objects[1]);
    }
}
