//! The trajectory prior a PhysiFormer's output may correct ([`TrajectoryPrior`]): where each
//! vertex would go without contacts.

use super::config::{PhysiConfig, TrajectoryPrior};
use super::scene::MeshScene;

/// The prior trajectory of `scene` over `frames` frames (`[frames, V, 3]` flattened, metres),
/// or `None` without a prior ([`TrajectoryPrior`]). The ballistic kinds move each vertex from
/// its initial position with its initial velocity under gravity and keep it in the box,
/// vertex by vertex or, for `ObjectBallistic`, object by object.
pub fn prior_trajectory(
    config: &PhysiConfig,
    scene: &MeshScene,
    frames: usize,
) -> Option<Vec<f32>> {
    let nv = scene.vertices();
    let mut out = Vec::with_capacity(frames * nv * 3);
    let free_flight = match config.prior {
        TrajectoryPrior::None => return None,
        TrajectoryPrior::Static => false,
        TrajectoryPrior::Ballistic | TrajectoryPrior::ObjectBallistic => true,
    };
    let e = config.box_half_extent;
    let per_object = config.prior == TrajectoryPrior::ObjectBallistic;
    for fr in 0..frames {
        let s = if free_flight {
            fr as f32 * config.dt_frame
        } else {
            0.0
        };
        let at = out.len();
        for (p, u) in scene.positions.iter().zip(&scene.velocities) {
            for c in 0..3 {
                let g = if free_flight { config.gravity[c] } else { 0.0 };
                out.push(p[c] + u[c] * s + 0.5 * g * s * s);
            }
        }
        if !free_flight {
            continue;
        }
        let frame = &mut out[at..];
        if per_object {
            // Shift each object back inside the box as a whole, axis by axis.
            for w in scene.vertex_offsets.windows(2) {
                let rows = &mut frame[w[0] * 3..w[1] * 3];
                for c in 0..3 {
                    let (lo, hi) = rows
                        .chunks_exact(3)
                        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), r| {
                            (lo.min(r[c]), hi.max(r[c]))
                        });
                    let shift = (-e - lo).max(0.0) - (hi - e).max(0.0);
                    for r in rows.chunks_exact_mut(3) {
                        r[c] += shift;
                    }
                }
            }
        }
        for x in frame.iter_mut() {
            *x = x.clamp(-e, e);
        }
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physiformer::scene::Material;

    fn scene() -> MeshScene {
        // One rigid object of two vertices on the floor, moving +x at 1 m/s.
        MeshScene {
            positions: vec![[0.0, 0.0, -1.0], [0.1, 0.0, -0.9]],
            velocities: vec![[1.0, 0.0, 0.0]; 2],
            vertex_offsets: vec![0, 2],
            materials: vec![Material::Rigid],
        }
    }

    #[test]
    fn the_object_prior_keeps_a_resting_object_rigid_and_the_vertex_prior_squashes_it() {
        let s = scene();
        let mut c = PhysiConfig::tiny();
        c.prior = TrajectoryPrior::ObjectBallistic;
        let p = prior_trajectory(&c, &s, 3).unwrap();
        let dt = c.dt_frame;
        // Frame 2: moved 2 dt along x, pushed back up onto the floor as a whole.
        assert!((p[12] - 2.0 * dt).abs() < 1e-6 && (p[14] + 1.0).abs() < 1e-6);
        assert!((p[17] - p[14] - 0.1).abs() < 1e-6, "gap kept: {p:?}");
        c.prior = TrajectoryPrior::Ballistic;
        let q = prior_trajectory(&c, &s, 3).unwrap();
        assert!(
            (q[17] - q[14] - 0.1).abs() > 1e-4,
            "vertex clamp changes the gap: {q:?}"
        );
        c.prior = TrajectoryPrior::Static;
        let r = prior_trajectory(&c, &s, 3).unwrap();
        assert_eq!(&r[12..18], &r[0..6]);
        c.prior = TrajectoryPrior::None;
        assert!(prior_trajectory(&c, &s, 3).is_none());
    }
}
