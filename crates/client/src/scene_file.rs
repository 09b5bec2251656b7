//! The JSON scene file format.
//!
//! A scene file is a [`json::RolloutRequest`] document, exactly the body of
//! `POST /v1/rollout`, so the same file works with the CLI, the client library and `curl -d @`:
//!
//! ```json
//! {
//!   "model": "rigidformer-small",
//!   "steps": 48,
//!   "dt_steps": 1,
//!   "scene": { "objects": [
//!     { "mesh": { "vertices": [[-0.25,-0.25,-0.25], ...], "faces": [[0,2,1], ...] },
//!       "pose": { "translation": [0, 0, 0.25], "rotation": [0, 0, 0, 1] },
//!       "velocity": { "linear": [0, 0, 0], "angular": [0, 0, 0] },
//!       "mass": 1.0, "friction": 0.5, "restitution": 0.3 } ] }
//! }
//! ```
//!
//! One extension is resolved on the client: an object may name a mesh file instead of
//! inlining it, `"mesh_file": "meshes/teapot.obj"` (OBJ or ASCII PLY, relative to the scene
//! file), optionally with `"samples"` and `"seed"` beside it; the client inlines the mesh
//! before sending, so servers only ever see the wire format.

use std::path::Path;

use dynaserve_api::json;
use serde_json::Value;

use crate::error::ClientError;

fn err(path: &Path, message: impl Into<String>) -> ClientError {
    ClientError::File {
        path: path.display().to_string(),
        message: message.into(),
    }
}

/// Reads a scene file, inlining `mesh_file` references.
pub fn load(path: impl AsRef<Path>) -> Result<json::RolloutRequest, ClientError> {
    let path = path.as_ref();
    let text = std::fs::read_to_string(path).map_err(|e| err(path, e.to_string()))?;
    let base = path.parent().unwrap_or(Path::new("."));
    parse(&text, base).map_err(|m| err(path, m))
}

/// Parses scene file text; `mesh_file` paths are resolved against `base`.
pub fn parse(text: &str, base: &Path) -> Result<json::RolloutRequest, String> {
    let mut doc: Value = serde_json::from_str(text).map_err(|e| e.to_string())?;
    if let Some(objects) = doc
        .get_mut("scene")
        .and_then(|s| s.get_mut("objects"))
        .and_then(Value::as_array_mut)
    {
        for (i, o) in objects.iter_mut().enumerate() {
            let Some(obj) = o.as_object_mut() else {
                continue;
            };
            let Some(file) = obj.remove("mesh_file") else {
                continue;
            };
            let file = file
                .as_str()
                .ok_or_else(|| format!("scene.objects[{i}].mesh_file must be a string"))?;
            let mut mesh = crate::mesh::load(base.join(file))
                .map_err(|e| format!("scene.objects[{i}].mesh_file: {e}"))?;
            if let Some(s) = obj.remove("samples") {
                mesh.samples = s
                    .as_u64()
                    .and_then(|s| u32::try_from(s).ok())
                    .ok_or_else(|| format!("scene.objects[{i}].samples must be a count"))?;
            }
            if let Some(s) = obj.remove("seed") {
                mesh.seed = s
                    .as_u64()
                    .ok_or_else(|| format!("scene.objects[{i}].seed must be an integer"))?;
            }
            obj.insert(
                "mesh".into(),
                serde_json::to_value(mesh).map_err(|e| e.to_string())?,
            );
        }
    }
    serde_json::from_value(doc).map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inlines_mesh_files() {
        let dir = std::env::temp_dir().join(format!("dynaserve-scene-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("tri.obj"),
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
        )
        .unwrap();
        let text = r#"{"steps": 3, "scene": {"objects": [
            {"mesh_file": "tri.obj", "samples": 64, "seed": 5,
             "pose": {"translation": [0, 0, 1]}, "mass": 1}]}}"#;
        let r = parse(text, &dir).unwrap();
        let m = r.scene.objects[0].mesh.as_ref().unwrap();
        assert_eq!(
            (m.vertices.len(), m.faces.len(), m.samples, m.seed),
            (4, 4, 64, 5)
        );
        assert!(parse(&text.replace("tri.obj", "missing.obj"), &dir).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
