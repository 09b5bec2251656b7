//! One model step for batches of MOVi-like scenes (10 objects x 512 points) split into phases,
//! one step of a 216-cube wrecking-ball scene (both for the `small` and `paper` configs), padded
//! vs block-diagonal decoder batching, the fused CPU kernels against the plain composition
//! (`fused_ab`, interleaved in one process), one scene split over the compute team against
//! none (`team_ab`), the anchor-pooling kernel alone (`avp_ab`), 256
//! against 512 points per object (`points_ab`), the floor projection off against on
//! (`floor_projection_ab`), the machine's matmul peak (`matmul_peak`), a
//! training iteration (forward + backward + AdamW) for the `small` and `paper` configs, and
//! training iterations with and without the fused kernels interleaved (`train_ab`).
//! One bench target because criterion binds one to a `main`; the cases share the scene
//! builders (`step_scenes/`) and the phase timer.
//!
//! `cargo bench -p dynaserve-model --bench step` (release). Phase medians are printed to
//! stdout; criterion reports the totals. `step_bundled_*` times the bundled default model's
//! architecture (`models/rigidformer-small/config.json`, or the model directory in
//! `DYNASERVE_BENCH_MODEL`) with random weights.

use std::hint::black_box;
use std::time::{Duration, Instant};

use candle_core::{DType, Device, Tensor};
use candle_nn::Optimizer;
use criterion::measurement::WallTime;
use criterion::{BenchmarkGroup, Criterion, criterion_group};
use dynaserve_model::{
    ModelConfig, PreparedScene, RigidFormer, SceneState, StepItem, StepProfile, WorldModel,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

mod step_scenes;

use step_scenes::{items, prepared_batch, train_batch, train_items, wrecking_ball};

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// A benchmark group of 10 samples after a 1 s warm-up, measured for `secs` seconds: every
/// case here times whole steps or kernels, milliseconds each, so few samples suffice.
fn short_group<'a>(
    c: &'a mut Criterion,
    name: impl Into<String>,
    secs: u64,
) -> BenchmarkGroup<'a, WallTime> {
    let mut group = c.benchmark_group(name);
    group
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(secs));
    group
}

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// Times `a` and `b` alternately `runs` times each and returns their medians in ms: both sides
/// see the same machine load, so their ratio holds even where absolute times do not.
fn interleaved(runs: usize, mut a: impl FnMut(), mut b: impl FnMut()) -> (f64, f64) {
    let (mut ta, mut tb) = (Vec::with_capacity(runs), Vec::with_capacity(runs));
    for _ in 0..runs {
        let t0 = Instant::now();
        a();
        ta.push(t0.elapsed());
        let t0 = Instant::now();
        b();
        tb.push(t0.elapsed());
    }
    (ms(median(ta)), ms(median(tb)))
}

fn print_phases(label: &str, model: &RigidFormer, batch: &[StepItem<'_>], runs: usize) {
    let mut profiles = Vec::with_capacity(runs);
    for _ in 0..runs {
        let mut p = StepProfile::default();
        black_box(model.step_profiled(batch, &mut p).expect("step"));
        profiles.push(p);
    }
    let pick = |f: fn(&StepProfile) -> Duration| ms(median(profiles.iter().map(f).collect()));
    println!(
        "phases {label}: contact+features {:.2} ms | encoder {:.2} ms | decoder {:.2} ms | anchors {:.2} ms | projection {:.2} ms | total {:.2} ms",
        pick(|p| p.features),
        pick(|p| p.encoder),
        pick(|p| p.decoder),
        pick(|p| p.anchors),
        pick(|p| p.projection),
        pick(|p| p.total()),
    );
}

fn bench_steps(c: &mut Criterion) {
    // The bundled default model's architecture (or `DYNASERVE_BENCH_MODEL`'s), random weights:
    // what the server runs unless told otherwise.
    let dir = std::env::var_os("DYNASERVE_BENCH_MODEL").map_or_else(
        || std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/rigidformer-small"),
        std::path::PathBuf::from,
    );
    let bundled = dynaserve_model::read_config(&dir).expect("bundled model config");
    for (name, config) in [
        ("small", ModelConfig::small()),
        ("paper", ModelConfig::paper()),
        ("bundled", bundled),
    ] {
        bench_steps_for(c, name, config);
    }
}

fn bench_steps_for(c: &mut Criterion, name: &str, config: ModelConfig) {
    let model = RigidFormer::new_frozen(config, 1, &Device::Cpu).expect("model");
    let mut group = short_group(c, format!("step_{name}_10x512"), 4);
    let mut per_scene = Vec::new();
    for b in [1usize, 8, 32, 128] {
        // Set up lazily: criterion only calls the closure when the benchmark is selected.
        let mut cache: Option<Vec<(PreparedScene, SceneState)>> = None;
        group.bench_function(format!("batch_{b}"), |bench| {
            let scenes = cache.get_or_insert_with(|| {
                let scenes = prepared_batch(&model, b, 10, 512, b as u64);
                let batch = items(&scenes);
                print_phases(
                    &format!("{name} b{b}"),
                    &model,
                    &batch,
                    if b >= 128 { 3 } else { 7 },
                );
                let t: Vec<Duration> = (0..3)
                    .map(|_| {
                        let t0 = Instant::now();
                        black_box(model.step(&batch).expect("step"));
                        t0.elapsed()
                    })
                    .collect();
                per_scene.push((b, ms(median(t)) / b as f64));
                scenes
            });
            let batch = items(scenes);
            bench.iter(|| black_box(model.step(&batch).expect("step")))
        });
    }
    group.finish();
    for (b, t) in &per_scene {
        println!("{name}: per-scene time at batch {b}: {t:.2} ms");
    }
    if let (Some(one), Some(t32)) = (
        per_scene.iter().find(|x| x.0 == 1),
        per_scene.iter().find(|x| x.0 == 32),
    ) {
        println!(
            "{name}: batching gain (per-scene time batch 1 / batch 32): {:.2}x",
            one.1 / t32.1
        );
    }
}

/// Two models on the same scenes, interleaved in one process (A B A B ..., 15 steps each):
/// prints both medians and the ratio `b / a` per case, then lets criterion time `a`. Cases
/// are `batch_N` (N 10-object x 512-point scenes) and `wrecking_ball`.
/// One side of an A/B: its label, its model, and a setting applied before each of its steps.
type Side<'a> = (&'a str, &'a RigidFormer, fn());

fn bench_model_ab(
    c: &mut Criterion,
    name: &str,
    (la, a, sa): Side,
    (lb, b, sb): Side,
    cases: &[&str],
) {
    let mut group = short_group(c, name, 3);
    for &case in cases {
        let mut cache: Option<Vec<(PreparedScene, SceneState)>> = None;
        group.bench_function(case, |bench| {
            let scenes = cache.get_or_insert_with(|| {
                let scenes = match case {
                    "wrecking_ball" => {
                        let (objects, state) = wrecking_ball(128);
                        vec![(a.prepare(objects).expect("valid scene"), state)]
                    }
                    _ => {
                        let n: usize = case[6..].parse().expect("batch size");
                        prepared_batch(a, n, 10, 512, n as u64)
                    }
                };
                let batch = items(&scenes);
                let (ta, tb) = interleaved(
                    15,
                    || {
                        sa();
                        drop(black_box(a.step(&batch).expect("step")))
                    },
                    || {
                        sb();
                        drop(black_box(b.step(&batch).expect("step")))
                    },
                );
                println!(
                    "{name} {case}: {la} {ta:.2} ms | {lb} {tb:.2} ms | {lb} / {la} {:.2}x",
                    tb / ta
                );
                scenes
            });
            let batch = items(scenes);
            sa();
            bench.iter(|| black_box(a.step(&batch).expect("step")))
        });
    }
    group.finish();
}

/// Fused CPU kernels against the plain candle composition.
fn bench_fused_ab(c: &mut Criterion) {
    let fused = RigidFormer::new_frozen(ModelConfig::small(), 1, &Device::Cpu).expect("model");
    let plain = RigidFormer::new_frozen(ModelConfig::small(), 1, &Device::Cpu)
        .expect("model")
        .with_fused_kernels(false);
    let cases = ["batch_1", "batch_8", "batch_32", "wrecking_ball"];
    bench_model_ab(
        c,
        "fused_ab",
        ("fused", &fused, || {}),
        ("composition", &plain, || {}),
        &cases,
    );
}

/// Scene groups on their own threads against every operation split across the threads.
fn bench_scene_threads_ab(c: &mut Criterion) {
    let grouped = RigidFormer::new_frozen(ModelConfig::small(), 1, &Device::Cpu).expect("model");
    let split = RigidFormer::new_frozen(ModelConfig::small(), 1, &Device::Cpu)
        .expect("model")
        .with_scene_threads(false);
    let cases = ["batch_2", "batch_8", "batch_32"];
    let (a, b): (Side, Side) = (
        ("scene groups", &grouped, || {}),
        ("split operations", &split, || {}),
    );
    bench_model_ab(c, "scene_threads_ab", a, b, &cases);
}

/// One scene's operations split over the compute team against the same step without it
/// (`dynaserve_model::team::set_enabled(false)`: small operations on the calling thread, large
/// ones still over rayon's pool).
fn bench_team_ab(c: &mut Criterion) {
    let model = RigidFormer::new_frozen(ModelConfig::small(), 1, &Device::Cpu).expect("model");
    let cases = ["batch_1", "wrecking_ball"];
    let (a, b): (Side, Side) = (
        ("team", &model, || dynaserve_model::team::set_enabled(true)),
        ("no team", &model, || {
            dynaserve_model::team::set_enabled(false)
        }),
    );
    bench_model_ab(c, "team_ab", a, b, &cases);
    dynaserve_model::team::set_enabled(true);
}

/// The fused anchor-vertex pooling kernel against the candle composition it replaces, on the
/// AVP shapes of a batch of 8 MOVi-like scenes (80 objects x 512 points) and of the wrecking
/// ball (216 objects x 128 points and one of 512, padded to 512 by the composition), `small`
/// widths; interleaved in one process, medians of 25 calls each.
fn bench_avp_ab(c: &mut Criterion) {
    use dynaserve_model::kernels::avp::{
        AnchorPooling, anchor_pooling, anchor_pooling_composed, padded_distances,
    };
    let cfg = ModelConfig::small();
    let (k, ch) = (cfg.anchors, cfg.point_dim);
    let mut group = short_group(c, "avp_ab", 2);
    for (case, counts) in [
        ("batch_8", vec![512usize; 80]),
        ("wrecking_ball", [vec![128usize; 216], vec![512]].concat()),
    ] {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let nmax = *counts.iter().max().expect("objects");
        let o = counts.len();
        let p: usize = counts.iter().sum();
        let mut objects = Vec::new();
        let (mut pad, mut mask) = (Vec::new(), Vec::new());
        let mut first = 0;
        for &n in &counts {
            objects.push((first, n));
            // Padding slots gather row `p`, the zero row the composition appends.
            pad.extend((0..nmax).map(|i| if i < n { first + i } else { p } as u32));
            mask.extend((0..nmax).map(|i| if i < n { 1f32 } else { 0.0 }));
            first += n;
        }
        // Each object's [K, n] distances, as the prepared scenes hold them.
        let rows: Vec<Vec<f32>> = counts
            .iter()
            .map(|&n| (0..k * n).map(|_| rng.random_range(0.0f32..0.09)).collect())
            .collect();
        let h: Vec<f32> = (0..p * ch)
            .map(|_| rng.random_range(-1.0f32..1.0))
            .collect();
        let dev = Device::Cpu;
        let h = Tensor::from_vec(h, (p, ch), &dev).expect("h");
        let maskt = Tensor::from_vec(mask, (o, 1, nmax), &dev).expect("mask");
        let padt = Tensor::from_vec(pad, o * nmax, &dev).expect("pad");
        let inv_sigma2 = 1.0 / (0.05f32 * 0.05);
        let inv = Tensor::new(&[inv_sigma2], &dev).expect("sigma");
        let rows: Vec<&[f32]> = rows.iter().map(Vec::as_slice).collect();
        let op = AnchorPooling {
            anchors: k,
            objects: &objects,
            d2: &rows,
            inv_sigma2,
        };
        // The composition on host data, as a step builds it: the padded distances and tensors
        // from the batch inputs.
        let composed = || {
            let d2 = padded_distances(&rows, k, nmax);
            let d2t = Tensor::from_vec(d2, (o, k, nmax), &dev).expect("d2");
            anchor_pooling_composed(&h, &d2t, &maskt, &padt, &inv, true).expect("composed")
        };
        let (a, b) = interleaved(
            25,
            || drop(black_box(anchor_pooling(&h, &op).expect("fused"))),
            || drop(black_box(composed())),
        );
        println!(
            "avp_ab {case}: fused {a:.3} ms | composition {b:.3} ms | composition / fused {:.2}x",
            b / a
        );
        group.bench_function(case, |bench| {
            bench.iter(|| black_box(anchor_pooling(&h, &op).expect("fused")))
        });
    }
    group.finish();
}

/// A batch-8 step of 10-object scenes at 256 and at 512 points per object, interleaved 15 times
/// in one process (`small`, random weights): the speed side of choosing the nominal point count
/// (the accuracy side is in BENCHMARKS.md, "Accuracy against the point count").
fn bench_points_ab(c: &mut Criterion) {
    let model = RigidFormer::new_frozen(ModelConfig::small(), 1, &Device::Cpu).expect("model");
    let mut group = short_group(c, "points_ab", 3);
    let mut cache: Option<Vec<(PreparedScene, SceneState)>> = None;
    group.bench_function("batch_8_256", |bench| {
        let small = cache.get_or_insert_with(|| {
            let small = prepared_batch(&model, 8, 10, 256, 8);
            let large = prepared_batch(&model, 8, 10, 512, 8);
            let (small_batch, large_batch) = (items(&small), items(&large));
            let (a, b) = interleaved(
                15,
                || drop(black_box(model.step(&small_batch).expect("step"))),
                || drop(black_box(model.step(&large_batch).expect("step"))),
            );
            drop((small_batch, large_batch));
            println!(
                "points_ab batch 8: 256 points {a:.2} ms | 512 points {b:.2} ms | 512 / 256 {:.2}x",
                b / a
            );
            small
        });
        let batch = items(small);
        bench.iter(|| black_box(model.step(&batch).expect("step")))
    });
    group.finish();
}

/// The floor projection's cost: one step of batch 8 (10 objects x 512 points) by two
/// models with the same weights, without and with `floor_projection`, interleaved.
fn bench_floor_projection_ab(c: &mut Criterion) {
    let off = RigidFormer::new_frozen(ModelConfig::small(), 1, &Device::Cpu).expect("model");
    let on_config = ModelConfig {
        floor_projection: Some(0.002),
        ..ModelConfig::small()
    };
    let on = RigidFormer::new_frozen(on_config, 1, &Device::Cpu).expect("model");
    let mut group = short_group(c, "floor_projection_ab", 3);
    let mut cache: Option<Vec<(PreparedScene, SceneState)>> = None;
    group.bench_function("batch_8_with_projection", |bench| {
        let scenes = cache.get_or_insert_with(|| {
            let scenes = prepared_batch(&off, 8, 10, 512, 8);
            let batch = items(&scenes);
            let (a, b) = interleaved(
                15,
                || drop(black_box(off.step(&batch).expect("step"))),
                || drop(black_box(on.step(&batch).expect("step"))),
            );
            drop(batch);
            println!(
                "floor_projection_ab batch 8: off {a:.2} ms | on {b:.2} ms | on / off {:.3}x",
                b / a
            );
            scenes
        });
        let batch = items(scenes);
        bench.iter(|| black_box(on.step(&batch).expect("step")))
    });
    group.finish();
}

fn bench_wrecking_ball(c: &mut Criterion) {
    for (name, config) in [
        ("small", ModelConfig::small()),
        ("paper", ModelConfig::paper()),
    ] {
        let model = RigidFormer::new_frozen(config, 1, &Device::Cpu).expect("model");
        let mut cache: Option<(PreparedScene, SceneState)> = None;
        let mut group = short_group(c, "wrecking_ball", 4);
        group.bench_function(format!("216_cubes_128pts_{name}"), |bench| {
            let (scene, state) = cache.get_or_insert_with(|| {
                let (objects, state) = wrecking_ball(128);
                let scene = model.prepare(objects).expect("valid scene");
                let batch = [StepItem {
                    scene: &scene,
                    state: &state,
                    dt_steps: 1,
                }];
                print_phases(&format!("{name} wrecking ball"), &model, &batch, 5);
                (scene, state)
            });
            let batch = [StepItem {
                scene,
                state,
                dt_steps: 1,
            }];
            bench.iter(|| black_box(model.step(&batch).expect("step")))
        });
        group.finish();
    }
}

/// The decoder's dominant cost (L pre-norm attention + SwiGLU blocks) on 32 scenes of 3-10
/// objects + 16 registers, either padded `[32, M + R, D]` with key masks or packed into one
/// sequence with a block-diagonal mask.
fn bench_packing(c: &mut Criterion) {
    let dev = Device::Cpu;
    let (d, h, l, r, f) = (256usize, 8usize, 8usize, 16usize, 1024usize);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let counts: Vec<usize> = (0..32).map(|_| rng.random_range(3..=10)).collect();
    let rand_t = |shape: &[usize], rng: &mut ChaCha8Rng| -> Tensor {
        let n: usize = shape.iter().product();
        let s = 1.0 / (shape[shape.len() - 1] as f32).sqrt();
        Tensor::from_vec(
            (0..n)
                .map(|_| rng.random_range(-s..s))
                .collect::<Vec<f32>>(),
            shape,
            &dev,
        )
        .expect("tensor")
    };
    let weights: Vec<[Tensor; 4]> = (0..l)
        .map(|_| {
            [
                rand_t(&[3 * d, d], &mut rng),
                rand_t(&[d, d], &mut rng),
                rand_t(&[2 * f, d], &mut rng),
                rand_t(&[d, f], &mut rng),
            ]
        })
        .collect();
    let alpha = Tensor::ones(d, DType::F32, &dev).expect("ones");
    let blocks = |x: Tensor, mask: &Tensor| -> Tensor {
        let (b, t, _) = x.dims3().expect("dims");
        let mut x = x;
        for [qkv, wo, up, down] in &weights {
            let xn = candle_nn::ops::rms_norm(&x, &alpha, 1e-6).expect("norm");
            let y = xn
                .reshape((b * t, d))
                .expect("r")
                .matmul(&qkv.t().expect("t"))
                .expect("mm")
                .reshape((b, t, 3 * d))
                .expect("r");
            let sp = |i: usize| {
                y.narrow(2, i * d, d)
                    .expect("n")
                    .reshape((b, t, h, d / h))
                    .expect("r")
                    .transpose(1, 2)
                    .expect("t")
                    .contiguous()
                    .expect("c")
            };
            let (q, k, v) = (sp(0), sp(1), sp(2));
            let s = (q.matmul(&k.t().expect("t")).expect("mm") * (1.0 / ((d / h) as f64).sqrt()))
                .expect("s")
                .broadcast_add(mask)
                .expect("m");
            let a = candle_nn::ops::softmax_last_dim(&s)
                .expect("sm")
                .matmul(&v)
                .expect("mm");
            let a = a
                .transpose(1, 2)
                .expect("t")
                .reshape((b * t, d))
                .expect("r")
                .matmul(&wo.t().expect("t"))
                .expect("mm");
            x = (x + a.reshape((b, t, d)).expect("r")).expect("add");
            let xn = candle_nn::ops::rms_norm(&x, &alpha, 1e-6)
                .expect("norm")
                .reshape((b * t, d))
                .expect("r");
            let u = xn.matmul(&up.t().expect("t")).expect("mm");
            let g = (u.narrow(1, 0, f).expect("n").silu().expect("silu")
                * u.narrow(1, f, f).expect("n"))
            .expect("mul");
            x = (x + g
                .matmul(&down.t().expect("t"))
                .expect("mm")
                .reshape((b, t, d))
                .expect("r"))
            .expect("add");
        }
        x
    };
    // Padded.
    let mmax = *counts.iter().max().expect("non-empty");
    let t = mmax + r;
    let xp = rand_t(&[32, t, d], &mut rng);
    let mut mp = vec![0f32; 32 * t];
    for (s, &m) in counts.iter().enumerate() {
        for j in m..mmax {
            mp[s * t + j] = -1e9;
        }
    }
    let mp = Tensor::from_vec(mp, (32, 1, 1, t), &dev).expect("mask");
    // Block-diagonal packing.
    let total: usize = counts.iter().map(|m| m + r).sum();
    let xq = rand_t(&[1, total, d], &mut rng);
    let mut mq = vec![-1e9f32; total * total];
    let mut start = 0;
    for &m in &counts {
        for i in start..start + m + r {
            for j in start..start + m + r {
                mq[i * total + j] = 0.0;
            }
        }
        start += m + r;
    }
    let mq = Tensor::from_vec(mq, (1, 1, total, total), &dev).expect("mask");
    let mut group = short_group(c, "decoder_packing_32_scenes_d256_l8", 3);
    group.bench_function("padded", |bench| {
        bench.iter(|| black_box(blocks(xp.clone(), &mp)))
    });
    group.bench_function("block_diagonal", |bench| {
        bench.iter(|| black_box(blocks(xq.clone(), &mq)))
    });
    group.finish();
}

/// The machine's matrix-multiplication peak through candle: one f32 product of 1024 x 1024
/// matrices (2 GFLOP), printed as GFLOP/s next to criterion's time.
fn bench_matmul_peak(c: &mut Criterion) {
    let n = 1024usize;
    let a = Tensor::ones((n, n), DType::F32, &Device::Cpu).expect("a");
    let b = Tensor::ones((n, n), DType::F32, &Device::Cpu).expect("b");
    let mut group = short_group(c, "matmul_peak", 3);
    let mut printed = false;
    group.bench_function("f32_1024", |bench| {
        if !printed {
            // Warm the thread pool and the caches first: cold products made the printed figure
            // half criterion's on two threads.
            for _ in 0..5 {
                black_box(a.matmul(&b).expect("matmul"));
            }
            let t: Vec<Duration> = (0..7)
                .map(|_| {
                    let t0 = Instant::now();
                    black_box(a.matmul(&b).expect("matmul"));
                    t0.elapsed()
                })
                .collect();
            let s = median(t).as_secs_f64();
            println!(
                "matmul_peak: {:.1} GFLOP/s",
                2.0 * (n as f64).powi(3) / s / 1e9
            );
            printed = true;
        }
        bench.iter(|| black_box(a.matmul(&b).expect("matmul")))
    });
    group.finish();
}

fn bench_training(c: &mut Criterion) {
    let mut group = short_group(c, "train_iteration_16_scenes_3to10x256", 5);
    for (name, cfg) in [
        ("small", ModelConfig::small()),
        ("paper", ModelConfig::paper()),
    ] {
        let mut cache = None;
        group.bench_function(name, |bench| {
            let (model, data, opt) = cache.get_or_insert_with(|| {
                let model = RigidFormer::new(cfg.clone(), 2, &Device::Cpu).expect("model");
                println!("{name}: {} parameters", model.parameter_count());
                let data = train_batch(&model, 5);
                let opt = candle_nn::AdamW::new(
                    model.varmap().all_vars(),
                    candle_nn::ParamsAdamW {
                        lr: 1e-4,
                        ..Default::default()
                    },
                )
                .expect("optimiser");
                (model, data, opt)
            });
            let batch = train_items(data);
            bench.iter(|| {
                let out = model.train_forward(&batch).expect("forward");
                opt.backward_step(&out.loss).expect("step");
            })
        });
    }
    group.finish();
}

/// Training iterations with the fused kernels against the plain composition, interleaved in
/// one process (A B A B ..., 9 iterations each, both models from the same seed with their own
/// AdamW): prints the medians of the forward pass, the backward pass, the AdamW update and
/// the whole iteration for both, and the ratio.
fn bench_train_ab(c: &mut Criterion) {
    let mut group = short_group(c, "train_ab", 3);
    let mut cache = None;
    group.bench_function("small", |bench| {
        let (model, data, opt) = cache.get_or_insert_with(|| {
            let fused = RigidFormer::new(ModelConfig::small(), 2, &Device::Cpu).expect("model");
            let plain = RigidFormer::new(ModelConfig::small(), 2, &Device::Cpu)
                .expect("model")
                .with_fused_kernels(false);
            let data = train_batch(&fused, 5);
            let batch = train_items(&data);
            let adamw = |m: &RigidFormer| {
                candle_nn::AdamW::new(
                    m.varmap().all_vars(),
                    candle_nn::ParamsAdamW {
                        lr: 1e-4,
                        ..Default::default()
                    },
                )
                .expect("optimiser")
            };
            let mut sides = [(&fused, adamw(&fused), [(); 4].map(|_| Vec::new())), (&plain, adamw(&plain), [(); 4].map(|_| Vec::new()))];
            for _ in 0..9 {
                for (model, opt, times) in sides.iter_mut() {
                    let t0 = Instant::now();
                    let out = model.train_forward(&batch).expect("forward");
                    let t1 = Instant::now();
                    let grads = out.loss.backward().expect("backward");
                    let t2 = Instant::now();
                    opt.step(&grads).expect("step");
                    let t3 = Instant::now();
                    for (v, d) in times.iter_mut().zip([t1 - t0, t2 - t1, t3 - t2, t3 - t0]) {
                        v.push(d);
                    }
                }
            }
            let [a, b] = sides.map(|(_, _, t)| t.map(|v| ms(median(v))));
            println!(
                "train_ab small: fused forward {:.1} ms, backward {:.1} ms, adamw {:.1} ms, iteration {:.1} ms | composition {:.1}, {:.1}, {:.1}, {:.1} ms | composition / fused {:.2}x",
                a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3], b[3] / a[3]
            );
            let opt = adamw(&fused);
            drop(plain);
            (fused, data, opt)
        });
        let batch = train_items(data);
        bench.iter(|| {
            let out = model.train_forward(&batch).expect("forward");
            opt.backward_step(&out.loss).expect("step");
        })
    });
    group.finish();
}

criterion_group!(
    benches,
    bench_packing,
    bench_steps,
    bench_team_ab,
    bench_wrecking_ball,
    bench_fused_ab,
    bench_avp_ab,
    bench_scene_threads_ab,
    bench_points_ab,
    bench_floor_projection_ab,
    bench_matmul_peak,
    bench_training,
    bench_train_ab
);
fn main() {
    // SAFETY: first statement of main; criterion has not started any thread yet.
    unsafe { dynaserve_model::configure_compute(None) };
    dynaserve_model::keep_freed_memory();
    benches();
    Criterion::default().configure_from_args().final_summary();
}
