//! Rigid motions of sampled vertices: the least-squares rigid motion of a rigid object's
//! frame-0 vertices onto its vertices at a later frame (Kabsch, uniform weights, in f64), as
//! a fit with its residual ([`fit_rigid`], the pose the server reports per rigid object and
//! frame) and as a projection of a whole trajectory ([`project_rigid`]): the network predicts
//! vertices freely; the projection makes rigid objects exactly rigid and removes the part of
//! the error that is not a rigid motion.

use dynaserve_geometry::{KabschSolution, kabsch, quat};

use super::scene::{Material, MeshScene};
use crate::{ModelError, Pose};

/// The rigid motion best fitting a target point set from a reference one ([`fit_rigid`]).
#[derive(Clone, Debug)]
pub struct RigidMotionFit {
    /// The Kabsch solution: rotation, translation (metres) and both centroids.
    pub solution: KabschSolution,
    /// RMS distance of the target points from the moved reference points, metres.
    pub rms: f64,
}

impl RigidMotionFit {
    /// Moves a reference point by the fitted motion, metres.
    pub fn apply(&self, p: [f32; 3]) -> [f32; 3] {
        self.solution.apply(p.map(f64::from)).map(|c| c as f32)
    }

    /// The fitted motion as a pose of the body frame `reference - centroid(reference)`: the
    /// target centroid (metres) and the rotation (unit quaternion `[x, y, z, w]`).
    pub fn pose(&self) -> Result<Pose, ModelError> {
        let q = quat::from_rotation_matrix(&self.solution.rotation)
            .map_err(|e| ModelError::Internal(format!("rigid fit rotation: {e}")))?;
        let c = self.solution.target_centroid;
        Ok(Pose {
            translation: [c.x as f32, c.y as f32, c.z as f32],
            rotation: q.map(|v| v as f32),
        })
    }
}

/// The rigid motion best fitting `target` from `reference` (the same points in the same
/// order, metres) with its RMS residual. Errors for empty or unequal sets and non-finite
/// points.
pub fn fit_rigid(
    reference: &[[f32; 3]],
    target: &[[f32; 3]],
) -> Result<RigidMotionFit, ModelError> {
    let a: Vec<[f64; 3]> = reference.iter().map(|p| p.map(f64::from)).collect();
    let b: Vec<[f64; 3]> = target.iter().map(|p| p.map(f64::from)).collect();
    let solution =
        kabsch(&a, &b, None).map_err(|e| ModelError::InvalidInput(format!("rigid fit: {e}")))?;
    let sq: f64 = a
        .iter()
        .zip(&b)
        .map(|(x, y)| {
            let m = solution.apply(*x);
            (0..3).map(|k| (m[k] - y[k]).powi(2)).sum::<f64>()
        })
        .sum();
    Ok(RigidMotionFit {
        solution,
        rms: (sq / a.len() as f64).sqrt(),
    })
}

/// Projects the rigid objects of `trajectory` (`[frames, V, 3]` flattened, metres; frame 0 the
/// scene's initial positions) onto rigid motions of their frame-0 shape, in place. Elastic
/// objects are left as they are. Errors if the trajectory's size does not match the scene.
pub fn project_rigid(
    scene: &MeshScene,
    frames: usize,
    trajectory: &mut [f32],
) -> Result<(), ModelError> {
    let nv = scene.vertices();
    if trajectory.len() != frames * nv * 3 {
        return Err(ModelError::InvalidInput(format!(
            "trajectory holds {} values, expected {} (frames x vertices x 3)",
            trajectory.len(),
            frames * nv * 3
        )));
    }
    for (o, material) in scene.materials.iter().enumerate() {
        if *material != Material::Rigid {
            continue;
        }
        let (a, b) = (scene.vertex_offsets[o], scene.vertex_offsets[o + 1]);
        let reference = &scene.positions[a..b];
        for fr in 1..frames {
            let rows = &mut trajectory[(fr * nv + a) * 3..(fr * nv + b) * 3];
            let target: Vec<[f32; 3]> = rows.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect();
            let fit = fit_rigid(reference, &target)
                .map_err(|e| ModelError::Internal(format!("rigid fit of object {o}: {e}")))?;
            for (row, r) in rows.chunks_exact_mut(3).zip(reference) {
                row.copy_from_slice(&fit.apply(*r));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynaserve_geometry::metrics::rigidity_residual;

    #[test]
    fn rigid_objects_become_exactly_rigid_and_elastic_ones_are_kept() {
        let tetra = [
            [0.0, 0.0, 0.0],
            [0.2, 0.0, 0.0],
            [0.0, 0.2, 0.0],
            [0.0, 0.0, 0.2],
        ];
        let mut positions = tetra.to_vec();
        positions.extend(tetra.iter().map(|p| [p[0] + 0.5, p[1], p[2]]));
        let scene = MeshScene {
            velocities: vec![[0.0; 3]; 8],
            vertex_offsets: vec![0, 4, 8],
            materials: vec![Material::Rigid, Material::Elastic],
            positions: positions.clone(),
        };
        // Frame 1: both objects moved by 0.1 m in z and squashed by 10% in x (not rigid).
        let mut traj: Vec<f32> = positions.iter().flatten().copied().collect();
        for p in &positions {
            traj.extend([p[0] * 0.9, p[1], p[2] + 0.1]);
        }
        let before = traj.clone();
        project_rigid(&scene, 2, &mut traj).unwrap();
        let at = |t: &[f32], k: usize| -> Vec<[f32; 3]> {
            (0..4)
                .map(|i| {
                    let r = (8 + k * 4 + i) * 3;
                    [t[r], t[r + 1], t[r + 2]]
                })
                .collect()
        };
        let residual = rigidity_residual(&tetra, &at(&traj, 0)).unwrap();
        assert!(residual < 1e-12, "{residual}");
        assert!(rigidity_residual(&tetra, &at(&before, 0)).unwrap() > 1e-5);
        assert_eq!(at(&traj, 1), at(&before, 1), "the elastic object changed");
        assert_eq!(&traj[..24], &before[..24], "frame 0 changed");
        assert!(project_rigid(&scene, 3, &mut traj).is_err());
    }
}
