//! Imports a checkpoint of the official PhysiFormer code into a model directory.
//!
//! The official training writes a PyTorch pickle (`torch.save`): `model` (the denoiser's state
//! dict, names prefixed `net.`), `ema.shadow` (the EMA weights, same names; what the official
//! inference uses by default) and `args` (the training arguments the inference reads). This
//! module reads that file with candle's pickle reader (no Python), or a safetensors export of
//! the state dict with the arguments as JSON beside it, and writes `config.json`,
//! `model.safetensors` (f32, the state dict's names without `net.`) and `card.md`.
//!
//! Every argument the official inference reads is either taken into the configuration or
//! refused with a message naming it ([`config_from`]).

use std::collections::HashMap;
use std::io::Read;
use std::path::Path;

use candle_core::pickle::{Object, Stack};
use candle_core::{DType, Device, Tensor};
use serde_json::{Map, Value};

use super::config::{DEFAULT_PATTERN, OfficialConfig, TIME_FEATURES};
use crate::ModelError;
use crate::physiformer::config::{PHYSI_FORMAT_VERSION, PHYSIFORMER, PhysiConfig, TrajectoryPrior};

/// Frames of the official data: 49 frames of 5 solver steps of 1/240 s.
pub const OFFICIAL_DT_FRAME: f32 = 5.0 / 240.0;

/// What an imported checkpoint holds: its weights (official names without `net.`) and the
/// training arguments as JSON.
pub struct OfficialCheckpoint {
    /// Weights by name.
    pub tensors: HashMap<String, Tensor>,
    /// The saved training arguments (an empty object when the file has none).
    pub args: Map<String, Value>,
    /// Which weights were taken: `"ema.shadow"` or `"model"` (or `"safetensors"`).
    pub source: String,
}

fn bad(m: impl Into<String>) -> ModelError {
    ModelError::Checkpoint(m.into())
}

/// A pickled Python value as JSON (numbers, strings, booleans, lists, dicts; anything else
/// as null).
fn to_json(o: &Object) -> Value {
    match o {
        Object::Int(i) => Value::from(*i),
        Object::Long(i) => Value::from(*i),
        Object::Float(f) => serde_json::Number::from_f64(*f).map_or(Value::Null, Value::Number),
        Object::Unicode(s) => Value::from(s.clone()),
        Object::Bool(b) => Value::from(*b),
        Object::Tuple(v) | Object::List(v) => Value::Array(v.iter().map(to_json).collect()),
        Object::Dict(kv) => Value::Object(
            kv.iter()
                .filter_map(|(k, v)| match k {
                    Object::Unicode(k) => Some((k.clone(), to_json(v))),
                    _ => None,
                })
                .collect(),
        ),
        _ => Value::Null,
    }
}

fn dict_get<'a>(o: &'a Object, key: &str) -> Option<&'a Object> {
    match o {
        Object::Dict(kv) => kv
            .iter()
            .find(|(k, _)| matches!(k, Object::Unicode(s) if s == key))
            .map(|(_, v)| v),
        _ => None,
    }
}

/// Reads one tensor of a PyTorch zip archive from its storage entry.
fn read_tensor(
    zip: &mut zip::ZipArchive<std::io::BufReader<std::fs::File>>,
    info: &candle_core::pickle::TensorInfo,
) -> Result<Tensor, ModelError> {
    if !info.layout.is_contiguous() {
        return Err(bad(format!(
            "tensor {:?} is stored strided; save a contiguous copy",
            info.name
        )));
    }
    let mut bytes = Vec::new();
    zip.by_name(&info.path)
        .map_err(|e| bad(format!("tensor {:?}: {e}", info.name)))?
        .read_to_end(&mut bytes)?;
    let size = info.dtype.size_in_bytes();
    let start = info.layout.start_offset() * size;
    let len = info.layout.shape().elem_count() * size;
    let data = bytes.get(start..start + len).ok_or_else(|| {
        bad(format!(
            "tensor {:?}: storage of {} bytes is shorter than its view",
            info.name,
            bytes.len()
        ))
    })?;
    Ok(Tensor::from_raw_buffer(
        data,
        info.dtype,
        info.layout.dims(),
        &Device::Cpu,
    )?)
}

/// Reads an official `.pt` checkpoint: the EMA weights when `use_ema` and present (as the
/// official inference does by default), else `model`; and `args`.
pub fn read_pt(path: &Path, use_ema: bool) -> Result<OfficialCheckpoint, ModelError> {
    let file = std::fs::File::open(path)
        .map_err(|e| bad(format!("cannot open {}: {e}", path.display())))?;
    let mut zip = zip::ZipArchive::new(std::io::BufReader::new(file)).map_err(|e| {
        bad(format!(
            "{} is not a PyTorch zip checkpoint ({e}); pass a .pt written by torch.save or a \
             .safetensors export",
            path.display()
        ))
    })?;
    let pkl = zip
        .file_names()
        .filter_map(|n| n.ok().map(|n| n.into_owned()))
        .find(|n| n.ends_with("data.pkl"))
        .ok_or_else(|| bad(format!("{} holds no data.pkl", path.display())))?;
    let mut raw = Vec::new();
    zip.by_name(&pkl)
        .map_err(|e| bad(e.to_string()))?
        .read_to_end(&mut raw)?;
    let mut stack = Stack::empty();
    stack
        .read_loop(&mut std::io::BufReader::new(raw.as_slice()))
        .map_err(|e| bad(format!("cannot parse the checkpoint's pickle: {e}")))?;
    let top = stack
        .finalize()
        .map_err(|e| bad(format!("cannot parse the checkpoint's pickle: {e}")))?;
    let ema = dict_get(&top, "ema").and_then(|e| dict_get(e, "shadow"));
    let (state, source) = match (use_ema, ema, dict_get(&top, "model")) {
        (true, Some(s), _) => (s, "ema.shadow"),
        (_, _, Some(m)) => (m, "model"),
        (false, Some(_), None) => {
            return Err(bad(
                "the checkpoint has EMA weights only; import them with EMA on",
            ));
        }
        _ if matches!(top, Object::Dict(_)) && dict_get(&top, "args").is_none() => {
            (&top, "state dict")
        }
        _ => return Err(bad("the checkpoint has neither `model` nor `ema.shadow`")),
    };
    let args = match dict_get(&top, "args").map(to_json) {
        Some(Value::Object(m)) => m,
        _ => Map::new(),
    };
    let dir = std::path::PathBuf::from(pkl.strip_suffix(".pkl").unwrap_or(&pkl));
    let Object::Dict(entries) = state.clone() else {
        return Err(bad(format!("`{source}` is not a state dict")));
    };
    let mut tensors = HashMap::new();
    for (name, value) in entries {
        let Some(info) = value
            .into_tensor_info(name, &dir)
            .map_err(|e| bad(format!("reading `{source}`: {e}")))?
        else {
            continue;
        };
        let t = read_tensor(&mut zip, &info)?;
        let key = info
            .name
            .strip_prefix("net.")
            .unwrap_or(&info.name)
            .to_string();
        tensors.insert(key, t);
    }
    if tensors.is_empty() {
        return Err(bad(format!("`{source}` holds no tensors")));
    }
    Ok(OfficialCheckpoint {
        tensors,
        args,
        source: source.to_string(),
    })
}

/// Reads a safetensors export of the official state dict (names with or without `net.`), and
/// the training arguments from `args` (a JSON object), if given.
pub fn read_safetensors(
    path: &Path,
    args: Option<&Path>,
) -> Result<OfficialCheckpoint, ModelError> {
    let loaded = candle_core::safetensors::load(path, &Device::Cpu)
        .map_err(|e| bad(format!("cannot read {}: {e}", path.display())))?;
    let tensors = loaded
        .into_iter()
        .map(|(k, v)| (k.strip_prefix("net.").unwrap_or(&k).to_string(), v))
        .collect();
    let args = match args {
        None => Map::new(),
        Some(p) => {
            let text = std::fs::read_to_string(p)
                .map_err(|e| bad(format!("cannot read {}: {e}", p.display())))?;
            match serde_json::from_str(&text) {
                Ok(Value::Object(m)) => m,
                _ => {
                    return Err(bad(format!(
                        "{} is not a JSON object of arguments",
                        p.display()
                    )));
                }
            }
        }
    };
    Ok(OfficialCheckpoint {
        tensors,
        args,
        source: "safetensors".into(),
    })
}

fn dims(t: &HashMap<String, Tensor>, name: &str) -> Option<Vec<usize>> {
    t.get(name).map(|x| x.dims().to_vec())
}

fn arg_f32(args: &Map<String, Value>, key: &str, default: f32) -> Result<f32, ModelError> {
    match args.get(key) {
        None | Some(Value::Null) => Ok(default),
        Some(v) => v
            .as_f64()
            .map(|x| x as f32)
            .ok_or_else(|| bad(format!("argument {key} = {v} is not a number"))),
    }
}

fn arg_usize(args: &Map<String, Value>, key: &str, default: usize) -> Result<usize, ModelError> {
    match args.get(key) {
        None | Some(Value::Null) => Ok(default),
        Some(v) => v
            .as_u64()
            .map(|x| x as usize)
            .ok_or_else(|| bad(format!("argument {key} = {v} is not a count"))),
    }
}

fn arg_bool(args: &Map<String, Value>, key: &str, default: bool) -> Result<bool, ModelError> {
    match args.get(key) {
        None | Some(Value::Null) => Ok(default),
        Some(Value::Bool(b)) => Ok(*b),
        Some(Value::Number(n)) => Ok(n.as_f64().unwrap_or(0.0) != 0.0),
        Some(v) => Err(bad(format!("argument {key} = {v} is not a boolean"))),
    }
}

/// A 3-vector argument: a list of three numbers or `"a,b,c"` (as the official parser takes).
fn arg_vec3(
    args: &Map<String, Value>,
    key: &str,
    default: [f32; 3],
) -> Result<[f32; 3], ModelError> {
    let parts: Vec<f64> = match args.get(key) {
        None | Some(Value::Null) => return Ok(default),
        Some(Value::Array(a)) => a.iter().filter_map(Value::as_f64).collect(),
        Some(Value::String(s)) => s
            .trim()
            .trim_start_matches('(')
            .trim_end_matches(')')
            .split(',')
            .filter(|p| !p.trim().is_empty())
            .map(|p| {
                p.trim()
                    .parse::<f64>()
                    .map_err(|_| bad(format!("argument {key} = {s:?} is not three numbers")))
            })
            .collect::<Result<_, _>>()?,
        Some(v) => return Err(bad(format!("argument {key} = {v} is not three numbers"))),
    };
    if parts.len() != 3 {
        return Err(bad(format!(
            "argument {key} must hold exactly three numbers"
        )));
    }
    Ok([parts[0] as f32, parts[1] as f32, parts[2] as f32])
}

/// The configuration of an official checkpoint: sizes from its state dict (the source of
/// truth the official loader checks against), conventions from its arguments with the
/// official inference's defaults. `max_objects` raises the scene object limit above the
/// checkpoint's slots (the official demo runs with 10). Refuses, naming it, every option this
/// implementation does not reproduce.
pub fn config_from(
    ckpt: &OfficialCheckpoint,
    max_objects: Option<usize>,
) -> Result<PhysiConfig, ModelError> {
    let t = &ckpt.tensors;
    let a = &ckpt.args;
    let need =
        |name: &str| dims(t, name).ok_or_else(|| bad(format!("the state dict has no {name}")));
    let x = need("x_embedder.weight")?;
    let hidden = x[0];
    if x[1] != 3 {
        return Err(bad(format!(
            "x_embedder takes {} features; expected 3 (positions)",
            x[1]
        )));
    }
    let depth = (0..)
        .take_while(|i| t.contains_key(&format!("blocks.{i}.attn.qkv.weight")))
        .count();
    if depth == 0 {
        return Err(bad("the state dict has no blocks"));
    }
    let head_dim = need("blocks.0.attn.q_norm.weight")?[0];
    if head_dim == 0 || !hidden.is_multiple_of(head_dim) {
        return Err(bad(format!(
            "q_norm width {head_dim} does not divide hidden {hidden}"
        )));
    }
    let ffn_hidden = need("blocks.0.mlp.w3.weight")?[1];
    let registers = dims(t, "reg_tokens").map_or(0, |d| d[1]);
    let scene_tokens = dims(t, "scene_token_base").map_or(0, |d| d[1]);
    let (scene_cond_dim, scene_cond_out_tokens) = match (
        dims(t, "scene_cond_embed.0.weight"),
        dims(t, "scene_cond_embed.2.weight"),
    ) {
        (Some(i), Some(o)) => (i[1], o[0] / hidden),
        _ => (0, 0),
    };
    if scene_tokens > 0 && scene_cond_dim == 0 {
        return Err(bad("scene tokens without a scene condition embedder"));
    }
    let material_dim = dims(t, "object_material_embed.0.weight").map_or(0, |d| d[1]);
    let slots = need("object_id_embed.weight")?[0].saturating_sub(1);
    let classes = need("y_embedder.embedding_table.weight")?[0].saturating_sub(1);
    let tf = need("t_embedder.mlp.0.weight")?[1];
    if tf != TIME_FEATURES {
        return Err(bad(format!(
            "the timestep embedder takes {tf} features; expected {TIME_FEATURES}"
        )));
    }
    if arg_bool(a, "delta_to_first_frame", false)? {
        return Err(bad(
            "argument delta_to_first_frame = true (the network predicts offsets from frame 0) is \
             not supported",
        ));
    }
    if arg_bool(a, "use_object_id_embed", false)? {
        return Err(bad(
            "argument use_object_id_embed = true is not supported (the official inference turns it off)",
        ));
    }
    if let Some(v) = a.get("block_attn_pattern")
        && !v.is_null()
        && v != &serde_json::json!(["spatial", "temporal", "object", "temporal"])
    {
        return Err(bad(format!(
            "argument block_attn_pattern = {v} is not supported"
        )));
    }
    let mode = a
        .get("material_mode")
        .and_then(Value::as_str)
        .unwrap_or("auto");
    if !matches!(mode, "auto" | "rigid" | "soft") {
        return Err(bad(format!(
            "argument material_mode = {mode:?} is not supported"
        )));
    }
    if material_dim == 12 {
        return Err(bad(
            "object_material_dim 12 (material vectors parsed from simulator metadata, inference \
             without --env_and_mat) is not supported; checkpoints with (softness, friction) rows \
             are",
        ));
    }
    let vertex_sampling = a
        .get("vertex_sampling")
        .and_then(Value::as_str)
        .unwrap_or("first");
    if vertex_sampling != "first" {
        return Err(bad(format!(
            "argument vertex_sampling = {vertex_sampling:?} is not supported (scenes are never subsampled)"
        )));
    }
    let method = a
        .get("sampling_method")
        .and_then(Value::as_str)
        .unwrap_or("heun");
    if !matches!(method, "heun" | "euler") {
        return Err(bad(format!(
            "argument sampling_method = {method:?} is not supported"
        )));
    }
    let official = OfficialConfig {
        hidden,
        depth,
        heads: hidden / head_dim,
        ffn_hidden,
        registers,
        scene_tokens,
        scene_cond_dim,
        scene_cond_out_tokens,
        material_dim,
        max_objects: slots,
        classes,
        label: 0,
        rope: arg_bool(a, "use_rope", true)?,
        max_frames: arg_usize(a, "max_frames", 128)?,
        pattern: DEFAULT_PATTERN.to_vec(),
        coord_scale: arg_f32(a, "coord_scale", 1.0)?,
        coord_shift: arg_f32(a, "coord_shift", 0.0)?,
        norm_mean: arg_vec3(a, "norm_mean", [0.0; 3])?,
        norm_std: arg_vec3(a, "norm_std", [1.0; 3])?,
        normalize_to_scene_box: arg_bool(a, "normalize_to_scene_box", false)?,
        velocity_condition: true,
        rigid_material: [
            arg_f32(a, "material_softness_rigid", 0.0)?,
            arg_f32(a, "material_friction_rigid", 0.01)?,
        ],
        elastic_material: [
            arg_f32(a, "material_softness_soft", 1.0)?,
            arg_f32(a, "material_friction_soft", 0.15)?,
        ],
    };
    official.validate()?;
    let frames = arg_usize(a, "num_frames", 32)?;
    let config = PhysiConfig {
        architecture: PHYSIFORMER.into(),
        format_version: PHYSI_FORMAT_VERSION,
        frames,
        dt_frame: OFFICIAL_DT_FRAME,
        box_half_extent: 1.0,
        gravity: [0.0, 0.0, -9.81],
        max_vertices: arg_usize(a, "max_vertices", 8192)?,
        max_objects: max_objects.unwrap_or(slots.max(10)),
        noise_scale: arg_f32(a, "noise_scale", 0.1)?,
        t_mu: arg_f32(a, "P_mean", -0.8)?,
        t_sigma: arg_f32(a, "P_std", 0.8)?,
        t_eps: arg_f32(a, "t_eps", 0.05)?,
        default_steps: arg_usize(a, "num_sampling_steps", 50)?,
        prior: TrajectoryPrior::None,
        correction_ramp_frames: 0,
        official,
    };
    // Also refuses num_frames beyond max_frames.
    config.validate()?;
    Ok(config)
}

/// The model card of an imported checkpoint.
pub fn card(
    name: &str,
    origin: &str,
    ckpt: &OfficialCheckpoint,
    config: &PhysiConfig,
    parameters: usize,
) -> String {
    let o = &config.official;
    let model = ckpt
        .args
        .get("model")
        .and_then(Value::as_str)
        .unwrap_or("(not recorded)");
    format!(
        "# {name}\n\n\
         PhysiFormer in the official architecture, imported from `{origin}` (weights: \
         `{source}`) with `dynaserve import physiformer`.\n\n\
         - Origin: a checkpoint of the official PhysiFormer code (its authors' training on \
           their simulated trajectories). Licence: that of the checkpoint's publisher; this \
           directory only converts its format. Check the publisher's terms before \
           redistributing it.\n\
         - Network: {params:.1} M parameters, width {w}, {blocks} blocks, {heads} heads, {regs} \
           registers, {scene} scene tokens; recorded model name `{model}`.\n\
         - Data conventions: {frames} frames of {dt:.5} s, box [-1, 1]^3 m, gravity -9.81 m/s^2 \
           along z; coordinate scale {cs}, shift {sh}, norm mean {nm:?}, std {ns:?}, scene-box \
           normalisation {nb}.\n\
         - Sampling: noise scale {noise}, {steps} steps by default (Heun, the last step Euler), \
           frame 0 clamped to the initial state.\n\n\
         Evaluation: run `dynaserve eval` on this directory; figures of a checkpoint depend on \
         its training, not on this import.\n",
        params = parameters as f64 / 1e6,
        source = ckpt.source,
        w = o.hidden,
        blocks = o.depth,
        heads = o.heads,
        regs = o.registers,
        scene = o.scene_tokens,
        frames = config.frames,
        dt = config.dt_frame,
        cs = o.coord_scale,
        sh = o.coord_shift,
        nm = o.norm_mean,
        ns = o.norm_std,
        nb = o.normalize_to_scene_box,
        noise = config.noise_scale,
        steps = config.default_steps,
    )
}

/// Converts every weight to f32 (the dtype the CPU path runs in).
pub fn to_f32(tensors: HashMap<String, Tensor>) -> Result<HashMap<String, Tensor>, ModelError> {
    tensors
        .into_iter()
        .map(|(k, v)| Ok((k, v.to_dtype(DType::F32)?)))
        .collect()
}
