//! The official PhysiFormer example scenes: a folder per scene with `metadata.json` (objects
//! with `vertex_count` and `material.kind`, scene `density`), `meshes/combined_frame_NNN.obj`
//! (every object's vertices at one frame, in object order, faces on frame 0) and
//! `vertex_velocities/combined_frame_000.npy` (`[V, 3]` float velocities at frame 0, m/s).
//! Read into the model's condition and true trajectory, with each object's mass (density
//! times the volume of its frame-0 mesh) for the momentum metric.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail, ensure};
use dynaserve_model::physiformer::flow::TrainScene;
use dynaserve_model::physiformer::scene::{Material, MeshScene};

/// One official example scene.
pub struct OfficialExample {
    /// The scene folder relative to the root given (`rigid/3`).
    pub name: String,
    /// Condition and true trajectory `[T, V, 3]`, metres.
    pub scene: TrainScene,
    /// Mass of every object, kg.
    pub masses: Vec<f64>,
}

/// True when `dir` holds official example scenes (a `metadata.json` beside a `meshes/`
/// folder, at any depth).
pub fn is_official_examples(dir: &Path) -> bool {
    !scene_dirs(dir).is_empty()
}

fn scene_dirs(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        if d.join("metadata.json").is_file() && d.join("meshes/combined_frame_000.obj").is_file() {
            out.push(d);
            continue;
        }
        if let Ok(rd) = std::fs::read_dir(&d) {
            for e in rd.flatten() {
                if e.path().is_dir() {
                    stack.push(e.path());
                }
            }
        }
    }
    // Natural order: rigid/2 before rigid/10.
    let key = |p: &PathBuf| -> Vec<(u64, String)> {
        p.iter()
            .map(|c| {
                let s = c.to_string_lossy().to_string();
                (s.parse::<u64>().unwrap_or(u64::MAX), s)
            })
            .collect()
    };
    out.sort_by_key(key);
    out
}

/// Vertices `[V]` and triangles (vertex index triples) of a mesh.
type Mesh = (Vec<[f32; 3]>, Vec<[u32; 3]>);

/// Vertices and triangles of an OBJ file (`v` and `f` lines; polygons fanned).
fn read_obj(path: &Path) -> anyhow::Result<Mesh> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let (mut v, mut f) = (Vec::new(), Vec::new());
    for (n, line) in text.lines().enumerate() {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                let c: Vec<f32> = it
                    .take(3)
                    .map(str::parse)
                    .collect::<Result<_, _>>()
                    .with_context(|| format!("{}:{}: bad vertex", path.display(), n + 1))?;
                ensure!(
                    c.len() == 3,
                    "{}:{}: a vertex needs 3 coordinates",
                    path.display(),
                    n + 1
                );
                v.push([c[0], c[1], c[2]]);
            }
            Some("f") => {
                let idx: Vec<u32> = it
                    .map(|t| {
                        t.split('/')
                            .next()
                            .unwrap_or("")
                            .parse::<u32>()
                            .map(|i| i - 1)
                    })
                    .collect::<Result<_, _>>()
                    .with_context(|| format!("{}:{}: bad face", path.display(), n + 1))?;
                for k in 1..idx.len().saturating_sub(1) {
                    f.push([idx[0], idx[k], idx[k + 1]]);
                }
            }
            _ => {}
        }
    }
    Ok((v, f))
}

/// A little-endian float `.npy` array (`<f4` or `<f8`, C order) as f32 with its shape.
fn read_npy(path: &Path) -> anyhow::Result<(Vec<f32>, Vec<usize>)> {
    let b = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    ensure!(
        b.len() > 10 && &b[..6] == b"\x93NUMPY",
        "{} is not a .npy file",
        path.display()
    );
    let (hlen, start) = if b[6] == 1 {
        (u16::from_le_bytes([b[8], b[9]]) as usize, 10)
    } else {
        (u32::from_le_bytes([b[8], b[9], b[10], b[11]]) as usize, 12)
    };
    let header = std::str::from_utf8(&b[start..start + hlen])?;
    ensure!(
        !header.contains("'fortran_order': True"),
        "{}: Fortran order is not supported",
        path.display()
    );
    let shape: Vec<usize> = header
        .split("'shape':")
        .nth(1)
        .and_then(|s| s.split(['(', ')']).nth(1))
        .map(|s| s.split(',').filter_map(|x| x.trim().parse().ok()).collect())
        .unwrap_or_default();
    let data = &b[start + hlen..];
    let values = if header.contains("'<f4'") {
        data.chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    } else if header.contains("'<f8'") {
        data.chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")) as f32)
            .collect()
    } else {
        bail!(
            "{}: only little-endian float32/float64 arrays are supported",
            path.display()
        );
    };
    Ok((values, shape))
}

/// Volume enclosed by a closed triangle mesh (absolute value of the signed volume), m^3.
fn volume(v: &[[f32; 3]], faces: &[[u32; 3]]) -> f64 {
    let s: f64 = faces
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|i| v[i as usize].map(f64::from));
            (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                + a[2] * (b[0] * c[1] - b[1] * c[0]))
                / 6.0
        })
        .sum();
    s.abs()
}

fn load_one(root: &Path, dir: &Path) -> anyhow::Result<OfficialExample> {
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("metadata.json"))?)
            .with_context(|| format!("{}: bad metadata.json", dir.display()))?;
    let objects = meta["objects"]
        .as_array()
        .with_context(|| format!("{}: metadata has no objects", dir.display()))?;
    let mut frames = 0;
    while dir
        .join(format!("meshes/combined_frame_{frames:03}.obj"))
        .is_file()
    {
        frames += 1;
    }
    ensure!(frames >= 2, "{}: fewer than 2 frames", dir.display());
    let (first, faces) = read_obj(&dir.join("meshes/combined_frame_000.obj"))?;
    let v = first.len();
    let mut offsets = vec![0usize];
    let mut materials = Vec::new();
    let mut masses = Vec::new();
    let scene_density = meta["density"].as_f64().unwrap_or(1000.0);
    for (i, o) in objects.iter().enumerate() {
        let n = o["vertex_count"]
            .as_u64()
            .with_context(|| format!("{}: object {i} has no vertex_count", dir.display()))?
            as usize;
        let (s, e) = (
            *offsets.last().expect("offsets start at 0"),
            offsets.last().expect("offsets") + n,
        );
        offsets.push(e);
        let kind = o["material"]["kind"].as_str().unwrap_or("rigid");
        materials.push(if kind == "rigid" {
            Material::Rigid
        } else {
            Material::Elastic
        });
        let density = o["material"]["rho"]
            .as_f64()
            .or(o["rho"].as_f64())
            .unwrap_or(scene_density);
        let own: Vec<[u32; 3]> = faces
            .iter()
            .filter(|f| f.iter().all(|&k| (k as usize) >= s && (k as usize) < e))
            .map(|f| f.map(|k| k - s as u32))
            .collect();
        masses.push(density * volume(&first[s..e.min(v)], &own));
    }
    ensure!(
        *offsets.last().expect("offsets") == v,
        "{}: metadata counts {} vertices, the OBJ {v}",
        dir.display(),
        offsets.last().expect("offsets")
    );
    let (vel, shape) = read_npy(&dir.join("vertex_velocities/combined_frame_000.npy"))?;
    ensure!(
        shape == [v, 3],
        "{}: velocities of shape {shape:?}, expected [{v}, 3]",
        dir.display()
    );
    let mut trajectory = Vec::with_capacity(frames * v * 3);
    for t in 0..frames {
        let (p, _) = read_obj(&dir.join(format!("meshes/combined_frame_{t:03}.obj")))?;
        ensure!(
            p.len() == v,
            "{}: frame {t} has {} vertices, frame 0 {v}",
            dir.display(),
            p.len()
        );
        trajectory.extend(p.iter().flatten());
    }
    let name = dir.strip_prefix(root).unwrap_or(dir).display().to_string();
    Ok(OfficialExample {
        name: if name.is_empty() {
            dir.display().to_string()
        } else {
            name
        },
        scene: TrainScene {
            scene: MeshScene {
                positions: first,
                velocities: vel.chunks(3).map(|c| [c[0], c[1], c[2]]).collect(),
                vertex_offsets: offsets,
                materials,
            },
            trajectory,
            frames,
        },
        masses,
    })
}

/// Every example scene under `root`, in natural order.
pub fn load_examples(root: &Path) -> anyhow::Result<Vec<OfficialExample>> {
    let dirs = scene_dirs(root);
    ensure!(
        !dirs.is_empty(),
        "no official example scenes (metadata.json + meshes/) under {}",
        root.display()
    );
    dirs.iter().map(|d| load_one(root, d)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn npy_and_obj_readers_and_the_volume_of_a_cube() {
        let dir = std::env::temp_dir().join(format!("dynaserve-npy-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let header = "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }";
        let mut h = header.to_string();
        while !(10 + h.len() + 1).is_multiple_of(64) {
            h.push(' ');
        }
        h.push('\n');
        let mut b = b"\x93NUMPY\x01\x00".to_vec();
        b.extend((h.len() as u16).to_le_bytes());
        b.extend(h.as_bytes());
        for x in [1f32, 2.0, 3.0, 4.0, 5.0, -6.0] {
            b.extend(x.to_le_bytes());
        }
        std::fs::write(dir.join("a.npy"), b).unwrap();
        let (v, shape) = read_npy(&dir.join("a.npy")).unwrap();
        assert_eq!(
            (v, shape),
            (vec![1.0, 2.0, 3.0, 4.0, 5.0, -6.0], vec![2, 3])
        );
        // A unit cube as quads: volume 1 whichever way its faces turn.
        let obj = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n\
                   f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n";
        std::fs::write(dir.join("c.obj"), obj).unwrap();
        let (v, f) = read_obj(&dir.join("c.obj")).unwrap();
        assert_eq!((v.len(), f.len()), (8, 12));
        assert!((volume(&v, &f) - 1.0).abs() < 1e-9);
        std::fs::remove_dir_all(dir).unwrap();
    }
}
