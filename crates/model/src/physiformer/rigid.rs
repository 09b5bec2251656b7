//! Rigid projection of a sampled trajectory: every rigid object's vertices at every frame are
//! replaced by the rigid motion of its frame-0 shape that fits them best (Kabsch, least
//! squares). The network predicts vertices freely; this makes rigid objects exactly rigid and
//! removes the part of the error that is not a rigid motion.

use dynaserve_geometry::kabsch;

use super::scene::{Material, MeshScene};
use crate::ModelError;

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
        let reference: Vec<[f64; 3]> = scene.positions[a..b]
            .iter()
            .map(|p| p.map(f64::from))
            .collect();
        for fr in 1..frames {
            let rows = &mut trajectory[(fr * nv + a) * 3..(fr * nv + b) * 3];
            let target: Vec<[f64; 3]> = rows
                .chunks_exact(3)
                .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
                .collect();
            let fit = kabsch::kabsch(&reference, &target, None)
                .map_err(|e| ModelError::Internal(format!("rigid fit of object {o}: {e}")))?;
            for (row, r) in rows.chunks_exact_mut(3).zip(&reference) {
                let y = fit.apply(*r);
                row.copy_from_slice(&[y[0] as f32, y[1] as f32, y[2] as f32]);
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
