//! How much of a one-step forecast's error is the velocity two frames cannot tell? On MOVi-B
//! scenes, predicts each object's centre one frame ahead ballistically from the finite
//! difference of frames t - 1 and t (what a two-frame model sees) and from rapier's true
//! velocity at t, and prints both RMSEs split by the contacts rapier reports at every physics
//! step of the intervals (t - 1, t] and (t, t + 1].
//!
//! `cargo run --release -p dynaserve-sim --example velocity_ambiguity -- [scenes]`
use dynaserve_sim::Generator;
use dynaserve_sim::random::scene_rng;
use dynaserve_sim::scene::{SimConfig, SimWorld};

/// Contacts of one object during one frame interval.
#[derive(Clone, Copy, Default)]
struct Touch {
    floor: bool,
    object: bool,
}

const REGIMES: [&str; 5] = [
    "free flight",
    "floor only",
    "object, also before t",
    "object, new after t",
    "object just before t",
];

fn main() {
    let scenes: u64 = std::env::args()
        .nth(1)
        .map(|s| s.parse().expect("scene count"))
        .unwrap_or(40);
    let cfg = SimConfig::default();
    let generator = Generator::movi_b();
    let (dt, h, n) = (
        cfg.dt_frame(),
        cfg.dt_substep(),
        cfg.integration_substeps() as f32,
    );
    // Per regime: squared error from two frames, from the true velocity, from three frames, count.
    let mut acc = [[0f64; 4]; REGIMES.len()];
    for s in 0..scenes {
        let spec = generator
            .sample(&mut scene_rng(99, "probe", "movi-b", s))
            .expect("scene");
        let m = spec.objects.len();
        let mut sim = SimWorld::new(&spec, &cfg).expect("world");
        let mut pos = vec![Vec::with_capacity(cfg.frames); m];
        let mut vel = vec![Vec::with_capacity(cfg.frames); m];
        // touch[f][i]: contacts of object i during the steps that lead to frame f.
        let mut touch = vec![vec![Touch::default(); m]; cfg.frames];
        for (f, touched) in touch.iter_mut().enumerate() {
            for _ in 0..if f > 0 { cfg.substeps } else { 0 } {
                sim.world.step();
                for p in sim.world.contact_pairs() {
                    if !p.has_any_active_contact() {
                        continue;
                    }
                    let a = sim.colliders.iter().position(|&c| c == p.collider1);
                    let b = sim.colliders.iter().position(|&c| c == p.collider2);
                    match (a, b) {
                        (Some(a), Some(b)) => {
                            touched[a].object = true;
                            touched[b].object = true;
                        }
                        (Some(a), None) | (None, Some(a)) => touched[a].floor = true,
                        (None, None) => {}
                    }
                }
            }
            for i in 0..m {
                let b = &sim.world.bodies[sim.bodies[i]];
                let (x, v) = (b.translation(), b.linvel());
                pos[i].push([x.x, x.y, x.z]);
                vel[i].push([v.x, v.y, v.z]);
            }
        }
        let g = spec.gravity;
        for i in 0..m {
            let x = &pos[i];
            for t in 4..cfg.frames - 1 {
                let (before, after) = (touch[t][i], touch[t + 1][i]);
                let r = match (before.object, after.object) {
                    (true, true) => 2,
                    (false, true) => 3,
                    (true, false) => 4,
                    _ if before.floor || after.floor => 1,
                    _ => 0,
                };
                for d in 0..3 {
                    let two_frames = 2.0 * x[t][d] - x[t - 1][d] + g[d] * dt * dt;
                    // Symplectic Euler over n substeps of h: v grows by g h before each move.
                    let true_v = x[t][d] + vel[i][t][d] * dt + g[d] * h * h * n * (n + 1.0) / 2.0;
                    // Constant acceleration, measured over frames t - 2, t - 1, t.
                    let three_frames = 3.0 * x[t][d] - 3.0 * x[t - 1][d] + x[t - 2][d];
                    acc[r][0] += ((two_frames - x[t + 1][d]) as f64).powi(2);
                    acc[r][1] += ((true_v - x[t + 1][d]) as f64).powi(2);
                    acc[r][2] += ((three_frames - x[t + 1][d]) as f64).powi(2);
                }
                acc[r][3] += 1.0;
            }
        }
    }
    println!("one frame ahead, {scenes} MOVi-B scenes: ballistic translation RMSE (m)");
    println!(
        "| contact | windows | from frames t-1, t | from the true velocity at t | constant acceleration over t-2, t-1, t |"
    );
    println!("| --- | --- | --- | --- | --- |");
    for (name, a) in REGIMES.iter().zip(acc) {
        let c = a[3].max(1.0);
        println!(
            "| {name} | {} | {:.4} | {:.4} | {:.4} |",
            a[3],
            (a[0] / c).sqrt(),
            (a[1] / c).sqrt(),
            (a[2] / c).sqrt()
        );
    }
}
