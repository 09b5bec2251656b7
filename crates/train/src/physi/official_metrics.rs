//! The official PhysiFormer evaluation's three metrics, as its `eval_publish_losses.py`
//! defines them, on trajectories `[T, V, 3]` (metres):
//!
//! - `mse`: mean over every frame, vertex and coordinate of the squared error, m^2 (a third of
//!   our per-vertex squared distance);
//! - `rigidity`: for frames `1..=48`, per object of at least 3 vertices (elastic ones too),
//!   the true frame-0 vertices Kabsch-aligned onto the predicted frame, the mean squared
//!   residual per coordinate; averaged over objects, then frames, m^2;
//! - momentum drift: the system momentum `P(t) = sum_o m_o c'_o(t)` from object vertex centres
//!   by backward differences, its drift `|P(t) - P(0)|` averaged over frames `1..=48`; the
//!   ratio is the mean predicted drift over the mean true drift, pooled over scenes.

use dynaserve_geometry::metrics::rigidity_residual;
use dynaserve_model::physiformer::scene::MeshScene;

/// Last frame of the rigidity and momentum averages (the official default).
pub const LAST_FRAME: usize = 48;

/// Mean squared error per coordinate, m^2.
pub fn mse(pred: &[f32], truth: &[f32]) -> f64 {
    let s: f64 = pred
        .iter()
        .zip(truth)
        .map(|(a, b)| f64::from(a - b).powi(2))
        .sum();
    s / pred.len().max(1) as f64
}

fn frame_points(traj: &[f32], v: usize, t: usize, r: std::ops::Range<usize>) -> Vec<[f32; 3]> {
    r.map(|i| {
        let k = (t * v + i) * 3;
        [traj[k], traj[k + 1], traj[k + 2]]
    })
    .collect()
}

/// The official rigidity residual of `pred` against the scene's frame 0 (the true one), m^2;
/// `None` when no object has 3 vertices.
pub fn rigidity(scene: &MeshScene, pred: &[f32], frames: usize) -> anyhow::Result<Option<f64>> {
    let v = scene.vertices();
    let last = LAST_FRAME.min(frames - 1);
    let (mut sum, mut n) = (0.0, 0usize);
    for t in 1..=last {
        let (mut fs, mut fn_) = (0.0, 0usize);
        for o in 0..scene.objects() {
            let r = scene.vertex_offsets[o]..scene.vertex_offsets[o + 1];
            if r.len() < 3 {
                continue;
            }
            let reference = &scene.positions[r.clone()];
            // Per coordinate: the official mean runs over points and their 3 coordinates.
            fs += rigidity_residual(reference, &frame_points(pred, v, t, r))? / 3.0;
            fn_ += 1;
        }
        if fn_ > 0 {
            sum += fs / fn_ as f64;
            n += 1;
        }
    }
    Ok((n > 0).then(|| sum / n as f64))
}

/// Mean over frames `1..=48` of `|P(t) - P(0)|` for the system momentum of `traj` with object
/// masses `masses` (kg) and frame interval `dt` (s).
pub fn momentum_drift(
    scene: &MeshScene,
    traj: &[f32],
    frames: usize,
    masses: &[f64],
    dt: f64,
) -> f64 {
    let v = scene.vertices();
    let centres: Vec<Vec<[f64; 3]>> = (0..frames)
        .map(|t| {
            (0..scene.objects())
                .map(|o| {
                    let r = scene.vertex_offsets[o]..scene.vertex_offsets[o + 1];
                    let n = r.len() as f64;
                    let mut c = [0f64; 3];
                    for p in frame_points(traj, v, t, r) {
                        for k in 0..3 {
                            c[k] += f64::from(p[k]) / n;
                        }
                    }
                    c
                })
                .collect()
        })
        .collect();
    let momentum = |t: usize| -> [f64; 3] {
        // Backward differences; frame 0 takes the first forward one.
        let (a, b) = if t == 0 { (0, 1) } else { (t - 1, t) };
        let mut p = [0f64; 3];
        for (o, m) in masses.iter().enumerate() {
            for k in 0..3 {
                p[k] += m * (centres[b][o][k] - centres[a][o][k]) / dt;
            }
        }
        p
    };
    let p0 = momentum(0);
    let last = LAST_FRAME.min(frames - 1);
    (1..=last)
        .map(|t| {
            let p = momentum(t);
            ((p[0] - p0[0]).powi(2) + (p[1] - p0[1]).powi(2) + (p[2] - p0[2]).powi(2)).sqrt()
        })
        .sum::<f64>()
        / last as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynaserve_model::physiformer::scene::Material;

    fn scene() -> MeshScene {
        MeshScene {
            positions: vec![[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]],
            velocities: vec![[0.0; 3]; 3],
            vertex_offsets: vec![0, 3],
            materials: vec![Material::Rigid],
        }
    }

    #[test]
    fn a_rigid_uniform_motion_has_no_rigidity_residual_and_no_drift() {
        let s = scene();
        let frames = 4;
        let mut traj = Vec::new();
        for t in 0..frames {
            for p in &s.positions {
                traj.extend([p[0] + 0.01 * t as f32, p[1], p[2]]);
            }
        }
        assert!(rigidity(&s, &traj, frames).unwrap().unwrap() < 1e-12);
        assert!(momentum_drift(&s, &traj, frames, &[2.0], 0.1) < 1e-5);
        assert_eq!(mse(&traj, &traj), 0.0);
        // Squashing the object breaks rigidity; accelerating it drifts the momentum.
        let mut bent = traj.clone();
        bent[(3 * 3 + 2) * 3 + 1] += 0.05;
        assert!(rigidity(&s, &bent, frames).unwrap().unwrap() > 1e-5);
        let mut fall = traj.clone();
        for t in 0..frames {
            for i in 0..3 {
                fall[(t * 3 + i) * 3 + 2] -= 0.01 * (t * t) as f32;
            }
        }
        // Backward velocities along z: -0.1, -0.1, -0.3, -0.5 m/s; momenta of 2 kg: -0.2,
        // -0.2, -0.6, -1.0; drifts 0, 0.4, 0.8 over frames 1..=3, mean 0.4.
        let d = momentum_drift(&s, &fall, frames, &[2.0], 0.1);
        assert!((d - 0.4).abs() < 1e-6, "{d}");
    }
}
