//! The official PhysiFormer data, read into the model's condition and true trajectory with
//! each object's mass (for the momentum metric):
//!
//! - **Example scene folders**: `metadata.json` (objects with `vertex_count` and
//!   `material.kind`, scene `density`), `meshes/combined_frame_NNN.obj` (every object's
//!   vertices at one frame, in object order, faces on frame 0) and
//!   `vertex_velocities/combined_frame_000.npy` (`[V, 3]` velocities at frame 0, m/s); masses
//!   are density times the volume of the frame-0 mesh. An object without a material kind
//!   takes the official demo's default by name (horse, fish, bunny elastic; others rigid).
//! - **Material variants** of such a folder (the out-of-distribution examples):
//!   `SCENE/all_rigid/vertices.npz`, `all_elastic`, `K_elastic_M_rigid` (`vertices [F, V, 3]`),
//!   the scene's condition with the materials the name gives.
//! - **Precomputed evaluation samples** (`sample_NNNNNN.npz`, as the official evaluation's
//!   preparation writes them): `vertices [F, V, 3]`, `mask [F, V]`, `object_ids [V]`,
//!   `num_objects`, `first_frame_velocity [V, 3]`, `object_masses [O]`; materials from a
//!   `metadata.json` beside the file, else from the folder's name (`2obj_elastic`).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail, ensure};

use super::npz::{npz_members, read_npy, read_npz};
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

/// True when `dir` holds official data (any of the three forms, at any depth).
pub fn is_official_examples(dir: &Path) -> bool {
    !sources(dir).is_empty()
}

/// Where official examples come from.
#[derive(Clone, Debug, PartialEq)]
enum Source {
    /// An example scene folder and the `vertices.npz` of its material variants.
    Folder {
        dir: PathBuf,
        variants: Vec<PathBuf>,
    },
    /// A precomputed evaluation sample.
    Precomputed(PathBuf),
}

impl Source {
    fn path(&self) -> &Path {
        match self {
            Source::Folder { dir, .. } => dir,
            Source::Precomputed(p) => p,
        }
    }
}

fn is_scene_folder(d: &Path) -> bool {
    d.join("metadata.json").is_file() && d.join("meshes/combined_frame_000.obj").is_file()
}

fn sources(dir: &Path) -> Vec<Source> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(rd) = std::fs::read_dir(&d) else {
            continue;
        };
        let mut entries: Vec<PathBuf> = rd.flatten().map(|e| e.path()).collect();
        entries.sort();
        if is_scene_folder(&d) {
            let variants = entries
                .iter()
                .map(|sub| sub.join("vertices.npz"))
                .filter(|npz| npz.is_file())
                .collect();
            out.push(Source::Folder { dir: d, variants });
            continue;
        }
        for e in entries {
            if e.is_dir() {
                stack.push(e);
            } else if e.extension().is_some_and(|x| x == "npz")
                && npz_members(&e).is_ok_and(|m| m.iter().any(|n| n == "first_frame_velocity"))
            {
                out.push(Source::Precomputed(e));
            }
        }
    }
    // Natural order: rigid/2 before rigid/10.
    let key = |s: &Source| -> Vec<(u64, String)> {
        s.path()
            .iter()
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
                            .ok()
                            .and_then(|i| i.checked_sub(1))
                    })
                    .collect::<Option<_>>()
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

/// A scene folder as an example, with the names of its objects (`""` where unnamed).
fn load_one(root: &Path, dir: &Path) -> anyhow::Result<(OfficialExample, Vec<String>)> {
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
    let mut names = Vec::new();
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
        // Without a material (the out-of-distribution scenes), the official demo's default
        // by object name.
        let name = o["name"].as_str().unwrap_or("");
        materials.push(match o["material"]["kind"].as_str() {
            Some("rigid") => Material::Rigid,
            Some(_) => Material::Elastic,
            None => default_material(name),
        });
        names.push(name.to_string());
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
    let vel = read_npy(&dir.join("vertex_velocities/combined_frame_000.npy"))?;
    let (vel, shape) = (vel.f32s(), vel.shape);
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
    let example = OfficialExample {
        name: relative(root, dir),
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
    };
    Ok((example, names))
}

/// The official demo's default materials of the out-of-distribution objects, by name:
/// these are elastic, the others rigid.
const DEFAULT_ELASTIC: [&str; 3] = ["horse", "fish", "bunny"];

/// The official demo's default material of an object named `name`.
fn default_material(name: &str) -> Material {
    if DEFAULT_ELASTIC.iter().any(|e| name.contains(e)) {
        Material::Elastic
    } else {
        Material::Rigid
    }
}

/// Materials of a variant folder's name for objects named `names`: `all_rigid`,
/// `all_elastic`, or `K_elastic_M_rigid` when the official demo's default assignment has K
/// elastic objects. Otherwise why the name does not give them.
fn variant_materials(variant: &str, names: &[String]) -> Result<Vec<Material>, String> {
    let n = names.len();
    match variant {
        "all_rigid" => return Ok(vec![Material::Rigid; n]),
        "all_elastic" => return Ok(vec![Material::Elastic; n]),
        _ => {}
    }
    let parts: Vec<&str> = variant.split('_').collect();
    let [k, "elastic", m, "rigid"] = parts[..] else {
        return Err(format!(
            "variant {variant}: expected all_rigid, all_elastic or K_elastic_M_rigid"
        ));
    };
    let (Ok(k), Ok(m)) = (k.parse::<usize>(), m.parse::<usize>()) else {
        return Err(format!("variant {variant}: counts are not numbers"));
    };
    if k + m != n {
        return Err(format!(
            "variant {variant}: {} objects named, the scene has {n}",
            k + m
        ));
    }
    let mats: Vec<Material> = names.iter().map(|s| default_material(s)).collect();
    let elastic = mats.iter().filter(|m| **m == Material::Elastic).count();
    if elastic != k {
        return Err(format!(
            "variant {variant}: the name does not say which {k} of {names:?} are elastic (the \
             default assignment has {elastic})"
        ));
    }
    Ok(mats)
}

/// A material variant of the scene folder example `base`: its condition with `materials` and
/// the true trajectory of `npz`.
fn load_variant(
    root: &Path,
    base: &OfficialExample,
    materials: Vec<Material>,
    npz: &Path,
) -> anyhow::Result<OfficialExample> {
    let arrays = read_npz(npz, &["vertices"])?;
    let verts = arrays
        .get("vertices")
        .with_context(|| format!("{}: no vertices", npz.display()))?;
    let v = base.scene.scene.vertices();
    ensure!(
        verts.shape.len() == 3 && verts.shape[1] == v && verts.shape[2] == 3,
        "{}: vertices of shape {:?}, the scene has {v} vertices",
        npz.display(),
        verts.shape
    );
    let mut scene = base.scene.scene.clone();
    scene.materials = materials;
    Ok(OfficialExample {
        name: relative(root, npz.parent().unwrap_or(npz)),
        scene: TrainScene {
            scene,
            trajectory: verts.f32s(),
            frames: verts.shape[0],
        },
        masses: base.masses.clone(),
    })
}

/// The materials of a precomputed sample: its `metadata.json` beside it (`material.kind` of
/// every object), else the name of its folder (`..._rigid` or `..._elastic`).
fn precomputed_materials(npz: &Path, objects: usize) -> anyhow::Result<Vec<Material>> {
    let dir = npz.parent().unwrap_or(Path::new("."));
    if let Ok(text) = std::fs::read_to_string(dir.join("metadata.json"))
        && let Ok(meta) = serde_json::from_str::<serde_json::Value>(&text)
        && let Some(objs) = meta["objects"].as_array()
        && objs.len() == objects
        && objs.iter().all(|o| o["material"]["kind"].is_string())
    {
        return Ok(objs
            .iter()
            .map(|o| match o["material"]["kind"].as_str() {
                Some("rigid") => Material::Rigid,
                _ => Material::Elastic,
            })
            .collect());
    }
    let name = dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    if name.ends_with("_rigid") {
        Ok(vec![Material::Rigid; objects])
    } else if name.ends_with("_elastic") {
        Ok(vec![Material::Elastic; objects])
    } else {
        bail!(
            "{}: no materials (a metadata.json beside it with material.kind per object, or a \
             folder named ..._rigid or ..._elastic)",
            npz.display()
        )
    }
}

/// A precomputed evaluation sample: the present vertices (`mask` at frame 0), grouped by
/// object id.
fn load_precomputed(root: &Path, npz: &Path) -> anyhow::Result<OfficialExample> {
    let names = [
        "vertices",
        "mask",
        "object_ids",
        "num_objects",
        "first_frame_velocity",
        "object_masses",
    ];
    let mut a = read_npz(npz, &names)?;
    let what = npz.display();
    let mut take = |k: &str| a.remove(k).with_context(|| format!("{what}: no {k}"));
    let verts = take("vertices")?;
    let mask = take("mask")?;
    let ids = take("object_ids")?;
    let objects = take("num_objects")?.values.first().copied().unwrap_or(0.0) as usize;
    let vel = take("first_frame_velocity")?;
    let masses = take("object_masses")?.values;
    ensure!(
        verts.shape.len() == 3 && verts.shape[2] == 3,
        "{what}: vertices of shape {:?}, expected [F, V, 3]",
        verts.shape
    );
    let (f, v) = (verts.shape[0], verts.shape[1]);
    ensure!(f >= 2, "{what}: fewer than 2 frames");
    ensure!(
        mask.shape == [f, v] && ids.shape == [v] && vel.shape == [v, 3],
        "{what}: mask {:?}, object_ids {:?}, first_frame_velocity {:?} do not match {f} frames \
         of {v} vertices",
        mask.shape,
        ids.shape,
        vel.shape
    );
    ensure!(
        objects >= 1 && masses.len() == objects,
        "{what}: {objects} objects, {} masses",
        masses.len()
    );
    // Present vertices, stably grouped by object.
    let mut order: Vec<usize> = (0..v).filter(|&i| mask.values[i] > 0.0).collect();
    for &i in &order {
        let id = ids.values[i];
        ensure!(
            id >= 0.0 && (id as usize) < objects,
            "{what}: vertex {i} has object id {id}, outside 0..{objects}"
        );
    }
    order.sort_by_key(|&i| ids.values[i] as usize);
    let mut offsets = vec![0usize];
    for o in 0..objects {
        let n = order
            .iter()
            .filter(|&&i| ids.values[i] as usize == o)
            .count();
        ensure!(n > 0, "{what}: object {o} has no present vertex");
        offsets.push(offsets[o] + n);
    }
    let at = |fr: usize, i: usize| {
        let b = (fr * v + i) * 3;
        [
            verts.values[b] as f32,
            verts.values[b + 1] as f32,
            verts.values[b + 2] as f32,
        ]
    };
    let positions: Vec<[f32; 3]> = order.iter().map(|&i| at(0, i)).collect();
    let velocities: Vec<[f32; 3]> = order
        .iter()
        .map(|&i| {
            [
                vel.values[i * 3] as f32,
                vel.values[i * 3 + 1] as f32,
                vel.values[i * 3 + 2] as f32,
            ]
        })
        .collect();
    let mut trajectory = Vec::with_capacity(f * order.len() * 3);
    for fr in 0..f {
        trajectory.extend(order.iter().flat_map(|&i| at(fr, i)));
    }
    Ok(OfficialExample {
        name: relative(root, npz),
        scene: TrainScene {
            scene: MeshScene {
                positions,
                velocities,
                vertex_offsets: offsets,
                materials: precomputed_materials(npz, objects)?,
            },
            trajectory,
            frames: f,
        },
        masses,
    })
}

/// `path` relative to `root` for display (the path itself when it is the root).
fn relative(root: &Path, path: &Path) -> String {
    let r = path
        .strip_prefix(root)
        .unwrap_or(path)
        .display()
        .to_string();
    if r.is_empty() {
        path.display().to_string()
    } else {
        r
    }
}

/// The official examples under a folder.
pub struct OfficialData {
    /// Scene folders, their material variants and precomputed samples, in natural order.
    pub examples: Vec<OfficialExample>,
    /// Material variants left out, with why (their name does not say which objects are
    /// elastic).
    pub skipped: Vec<String>,
}

/// Every official example under `root` (scene folders, their material variants, precomputed
/// samples); a variant whose materials its name does not give is skipped and reported, any
/// other unreadable file is an error naming it.
pub fn load_examples(root: &Path) -> anyhow::Result<OfficialData> {
    let found = sources(root);
    ensure!(
        !found.is_empty(),
        "no official examples (metadata.json + meshes/, or sample .npz files) under {}",
        root.display()
    );
    let mut out = OfficialData {
        examples: Vec::new(),
        skipped: Vec::new(),
    };
    for s in found {
        match s {
            Source::Folder { dir, variants } => {
                // The scene is read once; its variants share its condition.
                let (base, names) = load_one(root, &dir)?;
                let mut loaded = Vec::with_capacity(variants.len());
                for npz in variants {
                    let variant = npz
                        .parent()
                        .and_then(Path::file_name)
                        .map(|n| n.to_string_lossy().into_owned())
                        .unwrap_or_default();
                    match variant_materials(&variant, &names) {
                        Ok(m) => loaded.push(load_variant(root, &base, m, &npz)?),
                        Err(why) => out.skipped.push(format!("{}: {why}", npz.display())),
                    }
                }
                out.examples.push(base);
                out.examples.extend(loaded);
            }
            Source::Precomputed(p) => out.examples.push(load_precomputed(root, &p)?),
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn obj_reader_and_the_volume_of_a_cube() {
        let dir = std::env::temp_dir().join(format!("dynaserve-obj-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // A unit cube as quads: volume 1 whichever way its faces turn.
        let obj = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n\
                   f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n";
        std::fs::write(dir.join("c.obj"), obj).unwrap();
        let (v, f) = read_obj(&dir.join("c.obj")).unwrap();
        assert_eq!((v.len(), f.len()), (8, 12));
        assert!((volume(&v, &f) - 1.0).abs() < 1e-9);
        std::fs::write(dir.join("z.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n").unwrap();
        let err = read_obj(&dir.join("z.obj")).unwrap_err();
        assert!(err.to_string().contains("bad face"), "{err}");
        std::fs::remove_dir_all(dir).unwrap();
    }
}
