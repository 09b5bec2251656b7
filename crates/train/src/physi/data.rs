//! Mesh datasets as PhysiFormer training examples: every scene of one or more split
//! directories read into memory and laid out `[T, V, 3]`.

use std::path::PathBuf;

use anyhow::Context;
use dynaserve_model::physiformer::flow::TrainScene;
use dynaserve_model::physiformer::scene::{Material, MeshScene};
use dynaserve_sim::mesh_scenes::{MeshDatasetReader, MeshMaterial, MeshScene as SimScene};

/// The model's view of a simulated scene: condition plus true trajectory `[T, V, 3]`, metres.
pub fn to_train_scene(s: &SimScene) -> TrainScene {
    let v = s.num_vertices();
    let mut trajectory = Vec::with_capacity(s.frames * v * 3);
    for t in 0..s.frames {
        for i in 0..v {
            trajectory.extend(s.position(i, t));
        }
    }
    let mut offsets = vec![0];
    offsets.extend(s.objects.iter().map(|o| o.vertices.end));
    TrainScene {
        scene: MeshScene {
            positions: s.frame(0),
            velocities: (0..v).map(|i| s.initial_velocity(i)).collect(),
            vertex_offsets: offsets,
            materials: s
                .objects
                .iter()
                .map(|o| match o.material {
                    MeshMaterial::Rigid => Material::Rigid,
                    MeshMaterial::Elastic => Material::Elastic,
                })
                .collect(),
        },
        trajectory,
        frames: s.frames,
    }
}

/// Reads every scene of `dirs` (mesh dataset split directories).
pub fn load_scenes(dirs: &[PathBuf]) -> anyhow::Result<Vec<TrainScene>> {
    let mut out = Vec::new();
    for d in dirs {
        let r = MeshDatasetReader::open(d)
            .with_context(|| format!("cannot open mesh dataset {}", d.display()))?;
        for s in r.iter() {
            out.push(to_train_scene(&s?));
        }
    }
    anyhow::ensure!(!out.is_empty(), "no scenes in {dirs:?}");
    Ok(out)
}
