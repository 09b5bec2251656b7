//! `dynaserve parity`: does a device compute what the CPU computes? One RigidFormer step of a
//! batch of MOVi-B scenes and one PhysiFormer denoiser call on mesh scenes, each run on the
//! CPU and on the device from the same inputs, compared as relative errors.
//!
//! The scenes are simulated on the spot (rapier, fixed seeds), so the check needs no dataset.
//! Relative errors compare what the network changes, not absolute positions (which would make
//! any error look small):
//! - RigidFormer: the step's displacement of every dynamic object, `|d_dev - d_cpu| / |d_cpu|`
//!   over the batch (Euclidean norms over all objects), and likewise the rotation: the angle
//!   between the two predicted orientations against the angle each object turned.
//! - PhysiFormer: the denoiser's change of its noisy input, `|x_dev - x_cpu| / |x_cpu - z|`
//!   over every vertex and frame.

use std::path::PathBuf;

use anyhow::Context;
use dynaserve_model::physiformer::inputs::DenoiseItem;
use dynaserve_model::{Device, PhysiFormer, Pose, StepItem, device_from_name};
use dynaserve_sim::mesh_scenes::{MeshGenerateOptions, MeshSet, generate_mesh_scene};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::Serialize;

use crate::eval::ModelPredictor;
use crate::throughput::movi_b_step_inputs;

/// Arguments of `dynaserve parity`.
#[derive(clap::Args, Debug)]
pub struct ParityArgs {
    /// Device compared with the CPU: `cuda`, `cuda:N` (a build with `--features cuda`) or
    /// `cpu` (the CPU against itself: a check that the command works).
    #[arg(long, default_value = "cuda")]
    pub device: String,
    /// RigidFormer model directory.
    #[arg(long, default_value = "models/rigidformer-small")]
    pub rigid: PathBuf,
    /// PhysiFormer model directory.
    #[arg(long, default_value = "models/physiformer-small")]
    pub physi: PathBuf,
    /// MOVi-B scenes in the RigidFormer batch (one step each).
    #[arg(long, default_value_t = 8)]
    pub scenes: usize,
    /// Mesh scenes in the PhysiFormer call (half rigid, half elastic sets).
    #[arg(long, default_value_t = 2)]
    pub mesh_scenes: usize,
    /// Largest relative error accepted; the command fails above it.
    #[arg(long, default_value_t = 1e-4)]
    pub tolerance: f64,
    /// Write the figures as JSON to this file.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

/// One model's comparison.
#[derive(Clone, Debug, Serialize)]
pub struct ParityFigure {
    /// Model directory compared.
    pub model: String,
    /// What was run: scenes, objects or vertices.
    pub what: String,
    /// Relative error of the translation (RigidFormer) or trajectory change (PhysiFormer).
    pub relative: f64,
    /// RigidFormer: relative error of the rotation; PhysiFormer: none.
    pub relative_rotation: Option<f64>,
    /// Largest absolute difference of an output coordinate, metres.
    pub max_abs_m: f64,
    /// Seconds of the call on the CPU and on the device (the device's after one warm-up call).
    pub cpu_s: f64,
    /// See `cpu_s`.
    pub device_s: f64,
}

/// What `dynaserve parity` measured.
#[derive(Clone, Debug, Serialize)]
pub struct ParityReport {
    /// The device compared with the CPU.
    pub device: String,
    /// The tolerance applied to every relative error.
    pub tolerance: f64,
    /// RigidFormer's step, then PhysiFormer's denoiser call.
    pub figures: Vec<ParityFigure>,
    /// Every relative error is at most the tolerance.
    pub passed: bool,
}

/// Runs the comparison, prints it, writes `--json`, and fails when a relative error is above
/// the tolerance.
pub fn run(args: ParityArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.scenes >= 1 && args.mesh_scenes >= 1,
        "--scenes and --mesh-scenes must be at least 1"
    );
    let device = device_from_name(&args.device)?;
    let figures = vec![rigid(&args, &device)?, physi(&args, &device)?];
    let passed = figures.iter().all(|f| {
        f.relative <= args.tolerance && f.relative_rotation.is_none_or(|r| r <= args.tolerance)
    });
    let report = ParityReport {
        device: args.device.clone(),
        tolerance: args.tolerance,
        figures,
        passed,
    };
    println!("parity of {} against the CPU:", report.device);
    for f in &report.figures {
        let rot = f
            .relative_rotation
            .map(|r| format!(", rotation {r:.2e}"))
            .unwrap_or_default();
        println!(
            "  {} ({}): relative {:.2e}{rot}, max |diff| {:.2e} m; {:.3} s on the CPU, {:.3} s on {}",
            f.model, f.what, f.relative, f.max_abs_m, f.cpu_s, f.device_s, report.device
        );
    }
    println!(
        "{} (tolerance {:.0e})",
        if passed { "PASSED" } else { "FAILED" },
        args.tolerance
    );
    if let Some(path) = &args.json {
        std::fs::write(path, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    anyhow::ensure!(
        passed,
        "a relative error is above the tolerance {:.0e}",
        args.tolerance
    );
    Ok(())
}

fn timed<T>(f: impl FnOnce() -> anyhow::Result<T>) -> anyhow::Result<(T, f64)> {
    let t = std::time::Instant::now();
    let v = f()?;
    Ok((v, t.elapsed().as_secs_f64()))
}

/// One step of `args.scenes` MOVi-B scenes (k = 1 from frame 24) on both devices.
fn rigid(args: &ParityArgs, device: &Device) -> anyhow::Result<ParityFigure> {
    let cpu = ModelPredictor::load_on(&args.rigid, &Device::Cpu)
        .with_context(|| format!("loading {}", args.rigid.display()))?;
    let dev = ModelPredictor::load_on(&args.rigid, device)
        .with_context(|| format!("loading {} on {}", args.rigid.display(), args.device))?;
    let points = cpu.model().config().points_per_object.max(1);
    let (scenes, states) = movi_b_step_inputs(17, args.scenes, points)?;
    let objects: usize = scenes.iter().map(|s| s.objects.len()).sum();
    let prepared = scenes
        .iter()
        .map(|s| {
            Ok((
                cpu.model().prepare(cpu.inputs(s))?,
                dev.model().prepare(dev.inputs(s))?,
            ))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let items = |on_device: bool| -> Vec<StepItem<'_>> {
        prepared
            .iter()
            .zip(&states)
            .map(|((c, d), state)| StepItem {
                scene: if on_device { d } else { c },
                state,
                dt_steps: 1,
            })
            .collect()
    };
    let (on_cpu, cpu_s) = timed(|| Ok(cpu.model().step(&items(false))?))?;
    dev.model().step(&items(true))?;
    let (on_dev, device_s) = timed(|| Ok(dev.model().step(&items(true))?))?;
    let mut sq = [0f64; 4]; // translation diff, translation moved, angle diff, angle turned
    let mut max_abs = 0f64;
    for ((c, d), state) in on_cpu.iter().zip(&on_dev).zip(&states) {
        for ((pc, pd), now) in c.iter().zip(d).zip(&state.current) {
            for a in 0..3 {
                let diff = f64::from(pd.translation[a] - pc.translation[a]);
                let moved = f64::from(pc.translation[a] - now.translation[a]);
                sq[0] += diff * diff;
                sq[1] += moved * moved;
                max_abs = max_abs.max(diff.abs());
            }
            sq[2] += angle_between(pc, pd).powi(2);
            sq[3] += angle_between(now, pc).powi(2);
        }
    }
    Ok(ParityFigure {
        model: args.rigid.display().to_string(),
        what: format!("one step, {} scenes, {objects} objects", args.scenes),
        relative: ratio(sq[0], sq[1]),
        relative_rotation: Some(ratio(sq[2], sq[3])),
        max_abs_m: max_abs,
        cpu_s,
        device_s,
    })
}

/// One denoiser call at flow time 0.5 on `args.mesh_scenes` mesh scenes on both devices.
fn physi(args: &ParityArgs, device: &Device) -> anyhow::Result<ParityFigure> {
    let cpu = PhysiFormer::load(&args.physi, &Device::Cpu, false)
        .with_context(|| format!("loading {}", args.physi.display()))?;
    let dev = PhysiFormer::load(&args.physi, device, false)
        .with_context(|| format!("loading {} on {}", args.physi.display(), args.device))?;
    let mut scenes = Vec::new();
    for i in 0..args.mesh_scenes {
        let set = if i % 2 == 0 { MeshSet::D1 } else { MeshSet::D4 };
        let opts = MeshGenerateOptions::new(set, 17, "test", args.mesh_scenes);
        let (scene, _) = generate_mesh_scene(&opts, i as u64)?;
        scenes.push(crate::physi::data::to_train_scene(&scene));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let t = 0.5f32;
    let noisy: Vec<(usize, Vec<f32>)> = scenes
        .iter()
        .map(|s| {
            let frames = s.frames.min(cpu.config().frames);
            let len = frames * s.scene.positions.len() * 3;
            let z = s.trajectory[..len]
                .iter()
                .map(|x| {
                    let e: f32 = StandardNormal.sample(&mut rng);
                    t * x + (1.0 - t) * 0.1 * e
                })
                .collect();
            (frames, z)
        })
        .collect();
    let items: Vec<DenoiseItem<'_>> = scenes
        .iter()
        .zip(&noisy)
        .map(|(s, (frames, z))| DenoiseItem {
            scene: &s.scene,
            z,
            frames: *frames,
            t,
        })
        .collect();
    let (on_cpu, cpu_s) = timed(|| Ok(cpu.denoise(&items)?))?;
    dev.denoise(&items)?;
    let (on_dev, device_s) = timed(|| Ok(dev.denoise(&items)?))?;
    let (mut diff, mut change, mut max_abs) = (0f64, 0f64, 0f64);
    let mut vertices = 0;
    for ((c, d), (_, z)) in on_cpu.iter().zip(&on_dev).zip(&noisy) {
        for ((xc, xd), zi) in c.iter().zip(d).zip(z) {
            let e = f64::from(xd - xc);
            diff += e * e;
            change += f64::from(xc - zi).powi(2);
            max_abs = max_abs.max(e.abs());
        }
    }
    for s in &scenes {
        vertices += s.scene.positions.len();
    }
    Ok(ParityFigure {
        model: args.physi.display().to_string(),
        what: format!(
            "one denoiser call, {} scenes, {vertices} vertices",
            args.mesh_scenes
        ),
        relative: ratio(diff, change),
        relative_rotation: None,
        max_abs_m: max_abs,
        cpu_s,
        device_s,
    })
}

/// `sqrt(num / den)`, 0 when both are 0.
fn ratio(num: f64, den: f64) -> f64 {
    if num == 0.0 {
        0.0
    } else {
        (num / den.max(f64::MIN_POSITIVE)).sqrt()
    }
}

/// The angle between two poses' orientations, radians: that of `conj(a) * b`, from its
/// vector part (exactly 0 for equal orientations, unlike `acos` of a dot product near 1).
fn angle_between(a: &Pose, b: &Pose) -> f64 {
    let q = |p: &Pose| p.rotation.map(f64::from);
    let ([ax, ay, az, aw], [bx, by, bz, bw]) = (q(a), q(b));
    let w = aw * bw + ax * bx + ay * by + az * bz;
    let v = [
        aw * bx - bw * ax - (ay * bz - az * by),
        aw * by - bw * ay - (az * bx - ax * bz),
        aw * bz - bw * az - (ax * by - ay * bx),
    ];
    let norm = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    2.0 * norm.atan2(w.abs())
}
