//! Shard files: a split's scenes as safetensors tensors, encoded from and decoded into
//! [`SceneRecord`]s, with the checked tensor accessors the mesh shards share.

use std::collections::HashMap;
use std::path::Path;

use safetensors::tensor::{Dtype, SafeTensors, TensorView};

use super::manifest::{FORMAT, FORMAT_VERSION};
use super::records::{ObjectRecord, SceneRecord};
use crate::{Result, SimError};

fn f32_bytes<'a>(values: impl Iterator<Item = &'a f32>) -> Vec<u8> {
    values.flat_map(|v| v.to_le_bytes()).collect()
}

/// Serialises scenes into one shard (safetensors bytes). Every object must have `frames` poses
/// and `points` reference points.
pub fn encode_shard(scenes: &[SceneRecord], frames: usize, points: usize) -> Result<Vec<u8>> {
    let objects: Vec<&ObjectRecord> = scenes.iter().flat_map(|s| &s.objects).collect();
    for (i, o) in objects.iter().enumerate() {
        if o.positions.len() != frames
            || o.rotations.len() != frames
            || o.reference_points.len() != points
        {
            return Err(SimError::Invalid(format!(
                "object {i}: {} positions, {} rotations, {} points; expected {frames}, {frames}, \
                 {points}",
                o.positions.len(),
                o.rotations.len(),
                o.reference_points.len()
            )));
        }
    }
    let n = objects.len();
    let mut offsets = Vec::with_capacity(scenes.len() + 1);
    let mut acc = 0i64;
    offsets.push(acc);
    for s in scenes {
        acc += s.objects.len() as i64;
        offsets.push(acc);
    }
    let mut buffers: Vec<TensorBytes<'_>> = vec![
        (
            "scene_object_offsets",
            Dtype::I64,
            vec![scenes.len() + 1],
            offsets.iter().flat_map(|v| v.to_le_bytes()).collect(),
        ),
        (
            "positions",
            Dtype::F32,
            vec![n, frames, 3],
            f32_bytes(objects.iter().flat_map(|o| o.positions.iter().flatten())),
        ),
        (
            "rotations",
            Dtype::F32,
            vec![n, frames, 4],
            f32_bytes(objects.iter().flat_map(|o| o.rotations.iter().flatten())),
        ),
        (
            "reference_points",
            Dtype::F32,
            vec![n, points, 3],
            f32_bytes(
                objects
                    .iter()
                    .flat_map(|o| o.reference_points.iter().flatten()),
            ),
        ),
        (
            "mass",
            Dtype::F32,
            vec![n],
            f32_bytes(objects.iter().map(|o| &o.mass)),
        ),
        (
            "friction",
            Dtype::F32,
            vec![n],
            f32_bytes(objects.iter().map(|o| &o.friction)),
        ),
        (
            "restitution",
            Dtype::F32,
            vec![n],
            f32_bytes(objects.iter().map(|o| &o.restitution)),
        ),
        (
            "scale",
            Dtype::F32,
            vec![n, 3],
            f32_bytes(objects.iter().flat_map(|o| o.scale.iter())),
        ),
        (
            "shape_id",
            Dtype::I32,
            vec![n],
            objects
                .iter()
                .flat_map(|o| o.shape_id.to_le_bytes())
                .collect(),
        ),
        (
            "material",
            Dtype::I32,
            vec![n],
            objects
                .iter()
                .flat_map(|o| o.material.to_le_bytes())
                .collect(),
        ),
    ];
    // Written only when some object is kinematic, so shards without one keep their bytes.
    if objects.iter().any(|o| o.kinematic) {
        buffers.push((
            "kinematic",
            Dtype::I32,
            vec![n],
            objects
                .iter()
                .flat_map(|o| i32::from(o.kinematic).to_le_bytes())
                .collect(),
        ));
    }
    serialize_tensors(&buffers)
}

/// One tensor of a shard: name, dtype, shape and its values as little-endian bytes.
pub(crate) type TensorBytes<'a> = (&'a str, Dtype, Vec<usize>, Vec<u8>);

/// Serialises a shard's tensors into safetensors bytes whose header carries the one metadata
/// entry `format: dynaserve-sim/<version>`. One entry, because safetensors writes its metadata
/// map in hash order: with two entries the same shard would not be the same bytes on every
/// thread and run.
pub(crate) fn serialize_tensors(buffers: &[TensorBytes<'_>]) -> Result<Vec<u8>> {
    let views = buffers
        .iter()
        .map(|(name, dtype, shape, data)| {
            TensorView::new(*dtype, shape.clone(), data)
                .map(|v| (name.to_string(), v))
                .map_err(|e| SimError::Invalid(format!("tensor {name}: {e}")))
        })
        .collect::<Result<Vec<_>>>()?;
    let meta = HashMap::from([("format".to_string(), format!("{FORMAT}/{FORMAT_VERSION}"))]);
    safetensors::serialize(views, Some(meta))
        .map_err(|e| SimError::Invalid(format!("safetensors: {e}")))
}

/// A shard's tensors with checked accessors; errors name the shard file.
pub(crate) struct ShardTensors<'a> {
    st: SafeTensors<'a>,
    path: &'a Path,
}

impl<'a> ShardTensors<'a> {
    /// Parses the safetensors bytes of the shard at `path`.
    pub(crate) fn deserialize(bytes: &'a [u8], path: &'a Path) -> Result<Self> {
        let st = SafeTensors::deserialize(bytes).map_err(|e| SimError::Shard {
            path: path.to_path_buf(),
            message: format!("not a safetensors file: {e}"),
        })?;
        Ok(Self { st, path })
    }

    /// A [`SimError::Shard`] naming this shard.
    pub(crate) fn bad(&self, message: String) -> SimError {
        SimError::Shard {
            path: self.path.to_path_buf(),
            message,
        }
    }

    /// Whether the shard holds a tensor of this name.
    pub(crate) fn has(&self, name: &str) -> bool {
        self.st.tensor(name).is_ok()
    }

    /// The tensor's bytes after checking its dtype and shape.
    pub(crate) fn get(&self, name: &str, dtype: Dtype, shape: &[usize]) -> Result<&'a [u8]> {
        let t = self
            .st
            .tensor(name)
            .map_err(|e| self.bad(format!("tensor {name}: {e}")))?;
        if t.dtype() != dtype {
            return Err(self.bad(format!(
                "tensor {name} has dtype {:?}, expected {dtype:?}",
                t.dtype()
            )));
        }
        if t.shape() != shape {
            return Err(self.bad(format!(
                "tensor {name} has shape {:?}, expected {shape:?}",
                t.shape()
            )));
        }
        Ok(t.data())
    }

    /// A float tensor of the given shape, refusing non-finite values.
    pub(crate) fn f32s(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>> {
        let data = self.get(name, Dtype::F32, shape)?;
        let values: Vec<f32> = data
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        if values.iter().any(|v| !v.is_finite()) {
            return Err(self.bad(format!("tensor {name} holds non-finite values")));
        }
        Ok(values)
    }

    /// An int32 tensor of the given shape.
    pub(crate) fn i32s(&self, name: &str, shape: &[usize]) -> Result<Vec<i32>> {
        Ok(self
            .get(name, Dtype::I32, shape)?
            .chunks_exact(4)
            .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect())
    }

    /// An int64 offsets tensor `[len]` (any length when `None`) that starts at 0 and never
    /// decreases.
    pub(crate) fn offsets(&self, name: &str, len: Option<usize>) -> Result<Vec<usize>> {
        let len = match len {
            Some(n) => n,
            None => match self
                .st
                .tensor(name)
                .map_err(|e| self.bad(format!("tensor {name}: {e}")))?
                .shape()
            {
                [n] => *n,
                other => {
                    return Err(self.bad(format!(
                        "tensor {name} has shape {other:?}, expected one dimension"
                    )));
                }
            },
        };
        let v: Vec<i64> = self
            .get(name, Dtype::I64, &[len])?
            .chunks_exact(8)
            .map(|c| i64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
            .collect();
        if v.first() != Some(&0) || v.windows(2).any(|w| w[1] < w[0]) {
            return Err(self.bad(format!("{name} must start at 0 and not decrease")));
        }
        Ok(v.into_iter().map(|x| x as usize).collect())
    }
}

/// Decodes one shard against the manifest's frame and point counts.
pub fn decode_shard(
    bytes: &[u8],
    path: &Path,
    frames: usize,
    points: usize,
    dt_frame: f32,
) -> Result<Vec<SceneRecord>> {
    let sh = ShardTensors::deserialize(bytes, path)?;
    let offsets = sh.offsets("scene_object_offsets", None)?;
    let n = *offsets.last().unwrap_or(&0);
    let positions = sh.f32s("positions", &[n, frames, 3])?;
    let rotations = sh.f32s("rotations", &[n, frames, 4])?;
    let reference = sh.f32s("reference_points", &[n, points, 3])?;
    let mass = sh.f32s("mass", &[n])?;
    let friction = sh.f32s("friction", &[n])?;
    let restitution = sh.f32s("restitution", &[n])?;
    let scale = sh.f32s("scale", &[n, 3])?;
    let shape_id = sh.i32s("shape_id", &[n])?;
    let material = sh.i32s("material", &[n])?;
    let kinematic = kinematic_flags(&sh, n)?;
    let object = |i: usize| ObjectRecord {
        positions: positions[i * frames * 3..(i + 1) * frames * 3]
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect(),
        rotations: rotations[i * frames * 4..(i + 1) * frames * 4]
            .chunks_exact(4)
            .map(|c| [c[0], c[1], c[2], c[3]])
            .collect(),
        reference_points: reference[i * points * 3..(i + 1) * points * 3]
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect(),
        mass: mass[i],
        friction: friction[i],
        restitution: restitution[i],
        scale: [scale[3 * i], scale[3 * i + 1], scale[3 * i + 2]],
        shape_id: shape_id[i],
        material: material[i],
        kinematic: kinematic[i],
    };
    Ok(offsets
        .windows(2)
        .map(|w| SceneRecord {
            objects: (w[0]..w[1]).map(object).collect(),
            dt_frame,
        })
        .collect())
}

/// The `kinematic` flag of each of the shard's `n` objects (all false when the tensor is
/// absent, as in shards without a kinematic object); values other than 0 and 1 are refused.
fn kinematic_flags(sh: &ShardTensors, n: usize) -> Result<Vec<bool>> {
    if !sh.has("kinematic") {
        return Ok(vec![false; n]);
    }
    let k = sh.i32s("kinematic", &[n])?;
    if let Some(i) = k.iter().position(|&v| v != 0 && v != 1) {
        return Err(sh.bad(format!("kinematic[{i}] is {}, not 0 or 1", k[i])));
    }
    Ok(k.into_iter().map(|v| v == 1).collect())
}

/// One object's `([mass kg, friction, restitution], kinematic)`.
pub type ObjectParameters = ([f32; 3], bool);

/// The [`ObjectParameters`] of every object of one shard, one list per scene, in order,
/// without decoding the trajectories.
pub fn shard_object_parameters(bytes: &[u8], path: &Path) -> Result<Vec<Vec<ObjectParameters>>> {
    let sh = ShardTensors::deserialize(bytes, path)?;
    let offsets = sh.offsets("scene_object_offsets", None)?;
    let n = *offsets.last().unwrap_or(&0);
    let mass = sh.f32s("mass", &[n])?;
    let friction = sh.f32s("friction", &[n])?;
    let restitution = sh.f32s("restitution", &[n])?;
    let kinematic = kinematic_flags(&sh, n)?;
    Ok(offsets
        .windows(2)
        .map(|w| {
            (w[0]..w[1])
                .map(|i| ([mass[i], friction[i], restitution[i]], kinematic[i]))
                .collect()
        })
        .collect())
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A two-frame object one reference point large, moving 0.1 m along x.
    pub(crate) fn object(kinematic: bool) -> ObjectRecord {
        ObjectRecord {
            positions: vec![[0.0, 0.0, 0.5], [0.1, 0.0, 0.5]],
            rotations: vec![[0.0, 0.0, 0.0, 1.0]; 2],
            reference_points: vec![[0.5, 0.0, 0.0]],
            mass: 1.0,
            friction: 0.5,
            restitution: 0.3,
            scale: [1.0; 3],
            shape_id: 0,
            material: 0,
            kinematic,
        }
    }

    fn round_trip(objects: Vec<ObjectRecord>) -> (Vec<SceneRecord>, bool) {
        let scene = SceneRecord {
            objects,
            dt_frame: 0.5,
        };
        let bytes = encode_shard(std::slice::from_ref(&scene), 2, 1).unwrap();
        let stored = SafeTensors::deserialize(&bytes)
            .unwrap()
            .tensor("kinematic")
            .is_ok();
        let back = decode_shard(&bytes, Path::new("s"), 2, 1, 0.5).unwrap();
        assert_eq!(back, vec![scene]);
        (back, stored)
    }

    #[test]
    fn kinematic_objects_are_stored_and_read_back() {
        let (back, stored) = round_trip(vec![object(false), object(true)]);
        assert!(stored);
        let flags: Vec<bool> = back[0].objects.iter().map(|o| o.kinematic).collect();
        assert_eq!(flags, [false, true]);
        // Without a kinematic object the tensor is not written and reads back as all false.
        let (back, stored) = round_trip(vec![object(false)]);
        assert!(!stored);
        assert!(!back[0].objects[0].kinematic);
    }

    #[test]
    fn a_kinematic_flag_other_than_0_or_1_is_refused_by_both_readers() {
        let scene = SceneRecord {
            objects: vec![object(false), object(true)],
            dt_frame: 0.5,
        };
        let bytes = encode_shard(&[scene], 2, 1).unwrap();
        // The same shard with the second object's flag written as 2.
        let st = SafeTensors::deserialize(&bytes).unwrap();
        let names = st.names();
        let buffers: Vec<TensorBytes<'_>> = names
            .iter()
            .map(|name| {
                let t = st.tensor(name).unwrap();
                let data = if *name == "kinematic" {
                    [0i32, 2].iter().flat_map(|v| v.to_le_bytes()).collect()
                } else {
                    t.data().to_vec()
                };
                (*name, t.dtype(), t.shape().to_vec(), data)
            })
            .collect();
        let bad = serialize_tensors(&buffers).unwrap();
        let path = Path::new("bad.safetensors");
        for err in [
            decode_shard(&bad, path, 2, 1, 0.5).unwrap_err(),
            shard_object_parameters(&bad, path).unwrap_err(),
        ] {
            let message = err.to_string();
            assert!(
                message.contains("bad.safetensors") && message.contains("kinematic[1] is 2"),
                "{message}"
            );
        }
    }

    #[test]
    fn object_parameters_read_without_the_trajectories() {
        let mut heavy = object(false);
        heavy.mass = 3.0;
        heavy.friction = 0.9;
        heavy.restitution = 0.1;
        let scenes = [
            SceneRecord {
                objects: vec![object(false)],
                dt_frame: 0.5,
            },
            SceneRecord {
                objects: vec![heavy, object(true)],
                dt_frame: 0.5,
            },
        ];
        let bytes = encode_shard(&scenes, 2, 1).unwrap();
        let params = shard_object_parameters(&bytes, Path::new("s")).unwrap();
        assert_eq!(
            params,
            vec![
                vec![([1.0, 0.5, 0.3], false)],
                vec![([3.0, 0.9, 0.1], false), ([1.0, 0.5, 0.3], true)]
            ]
        );
    }
}
