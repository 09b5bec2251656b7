//! Scenes to send: JSON scene files (the `POST /v1/rollout` body, as in `examples/scenes/`,
//! read with the client crate's loader) or the client crate's seeded random scenes of boxes
//! resting on or falling towards the ground, never overlapping.

use std::path::PathBuf;

use dynaserve_api::json;
use dynaserve_client::random_scene::generate;

/// Where scenes come from.
#[derive(Clone, Debug)]
pub enum SceneSource {
    /// Scene files, used in turn (request `i` gets file `i % len`).
    Files {
        /// Paths, for the report.
        paths: Vec<PathBuf>,
        /// Parsed requests (mesh files inlined).
        requests: Vec<json::RolloutRequest>,
    },
    /// Generated scenes: request `i` gets [`generate`]`(seed + i, objects, points)`.
    Generated {
        /// Objects per scene.
        objects: usize,
        /// Surface points per object.
        points: usize,
        /// Base seed.
        seed: u64,
    },
}

impl SceneSource {
    /// Loads scene files.
    pub fn from_files(paths: &[PathBuf]) -> anyhow::Result<SceneSource> {
        anyhow::ensure!(!paths.is_empty(), "no scene files given");
        let requests = paths
            .iter()
            .map(dynaserve_client::scene_file::load)
            .collect::<Result<Vec<_>, _>>()?;
        for (p, r) in paths.iter().zip(&requests) {
            anyhow::ensure!(
                !r.scene.objects.is_empty(),
                "{}: the scene has no objects",
                p.display()
            );
        }
        Ok(SceneSource::Files {
            paths: paths.to_vec(),
            requests,
        })
    }

    /// Scene number `i`.
    pub fn scene(&self, i: usize) -> json::Scene {
        match self {
            SceneSource::Files { requests, .. } => requests[i % requests.len()].scene.clone(),
            SceneSource::Generated {
                objects,
                points,
                seed,
            } => generate(seed.wrapping_add(i as u64), *objects, *points),
        }
    }

    /// Steps and frames per step given by the first scene file, if any.
    pub fn file_steps(&self) -> Option<(u32, u32)> {
        match self {
            SceneSource::Files { requests, .. } => {
                requests.first().map(|r| (r.steps, r.dt_steps.max(1)))
            }
            SceneSource::Generated { .. } => None,
        }
    }

    /// One-line description for reports.
    pub fn describe(&self) -> String {
        match self {
            SceneSource::Files { paths, requests } => {
                let names: Vec<String> = paths.iter().map(|p| p.display().to_string()).collect();
                let objects: Vec<String> = requests
                    .iter()
                    .map(|r| r.scene.objects.len().to_string())
                    .collect();
                format!(
                    "scene files {} ({} objects)",
                    names.join(", "),
                    objects.join("/")
                )
            }
            SceneSource::Generated {
                objects,
                points,
                seed,
            } => format!("generated scenes: {objects} boxes x {points} points, seed {seed}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generated_sources_give_the_seeded_scene_of_each_request() {
        let src = SceneSource::Generated {
            objects: 4,
            points: 16,
            seed: 7,
        };
        assert_eq!(src.scene(3), generate(10, 4, 16));
        assert!(src.file_steps().is_none());
    }

    #[test]
    fn scene_files_are_loaded_with_the_client_loader() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/scenes");
        let src = SceneSource::from_files(&[dir.join("box_tower.json")]).unwrap();
        assert!(!src.scene(3).objects.is_empty());
        assert!(src.file_steps().unwrap().0 > 0);
        assert!(SceneSource::from_files(&[dir.join("missing.json")]).is_err());
    }
}
