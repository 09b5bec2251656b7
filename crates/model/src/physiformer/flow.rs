//! Flow matching in world coordinates: the training loss (x-prediction, v-loss, logit-normal
//! flow time) and the Heun (or Euler) sampler with frame 0 clamped to the scene's initial positions.
//!
//! `z_t = t x + (1 - t) e` with `e ~ N(0, noise_scale^2)`, `t = 0` noise and `t = 1` data;
//! the network predicts `x_hat`, the velocity is `v_hat = (x_hat - z_t) / max(1 - t, t_eps)`
//! and the loss is the mean over valid `(frame, vertex)` tokens of `|v_hat - (x - e)|^2`.

use candle_core::Tensor;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::PhysiFormer;
use super::config::PhysiConfig;
use super::inputs::PreparedItem;
use super::scene::MeshScene;
use crate::ModelError;
use crate::layers::Mode;

/// One standard normal draw (Box-Muller; deterministic for a seeded generator).
pub fn standard_normal(rng: &mut impl Rng) -> f32 {
    let u1: f32 = rng.random::<f32>().max(f32::MIN_POSITIVE);
    let u2: f32 = rng.random::<f32>();
    (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
}

/// A flow time from the logit-normal distribution `sigmoid(N(mu, sigma))`.
pub fn logit_normal(rng: &mut impl Rng, mu: f32, sigma: f32) -> f32 {
    let n = mu + sigma * standard_normal(rng);
    1.0 / (1.0 + (-n).exp())
}

/// One training example: a scene's condition and its true trajectory.
#[derive(Clone, Debug)]
pub struct TrainScene {
    /// Condition (frame-0 positions and velocities, objects, materials).
    pub scene: MeshScene,
    /// True positions `[frames, V, 3]` flattened, metres; frame 0 equals the condition's.
    pub trajectory: Vec<f32>,
    /// Frames of the trajectory.
    pub frames: usize,
}

/// The training loss of a batch, with the flow time drawn for each scene.
pub struct TrainLoss {
    /// Scalar v-loss (differentiable), m^2/s^2 in flow units.
    pub loss: Tensor,
    /// The flow time of each scene.
    pub times: Vec<f32>,
}

impl PhysiFormer {
    /// The flow-matching loss of `items`, each at its own logit-normal flow time drawn from
    /// `rng`, in the network's coordinates (metres for this crate's presets); training
    /// kernels, so every parameter receives its gradient. The mean over `(frame, vertex)`
    /// tokens of all items.
    pub fn train_loss(
        &self,
        items: &[&TrainScene],
        rng: &mut impl Rng,
    ) -> Result<TrainLoss, ModelError> {
        let c = &self.config;
        let mut times = Vec::with_capacity(items.len());
        let mut total: Option<Tensor> = None;
        let mut tokens = 0usize;
        for (i, it) in items.iter().enumerate() {
            let s = self
                .prepare(&it.scene, it.frames)
                .map_err(|e| ModelError::InvalidInput(format!("training scene {i}: {e}")))?
                .scene;
            let n = it.frames * it.scene.vertices() * 3;
            if it.trajectory.len() != n {
                return Err(ModelError::InvalidInput(format!(
                    "training scene {i}: the trajectory holds {} values, expected {n}",
                    it.trajectory.len()
                )));
            }
            let x = s.to_network(&it.trajectory);
            let t = logit_normal(rng, c.t_mu, c.t_sigma);
            let mut z = Vec::with_capacity(n);
            let mut v = Vec::with_capacity(n);
            for x in &x {
                let e = c.noise_scale * standard_normal(rng);
                z.push(t * x + (1.0 - t) * e);
                v.push(x - e);
            }
            let x_hat = self.net.forward(&s, &z, t, Mode::Training)?;
            let shape = (n / 3, 3);
            let z = Tensor::from_vec(z, shape, &self.device)?;
            let v = Tensor::from_vec(v, shape, &self.device)?;
            let v_hat = ((x_hat - z)? / f64::from((1.0 - t).max(c.t_eps)))?;
            let err = (v_hat - v)?.sqr()?.sum_all()?;
            total = Some(match total {
                Some(acc) => (acc + err)?,
                None => err,
            });
            tokens += n / 3;
            times.push(t);
        }
        let total = total.ok_or_else(|| ModelError::InvalidInput("no training scene".into()))?;
        Ok(TrainLoss {
            loss: (total / tokens as f64)?,
            times,
        })
    }
}

#[derive(Clone, Debug)]
enum Stage {
    /// The next evaluation is the predictor at the interval's start.
    Predict,
    /// The next evaluation is the corrector at the interval's end.
    Correct { z_prev: Vec<f32>, v1: Vec<f32> },
}

/// The integrator of a [`Sampler`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum SamplerKind {
    /// Heun (second order): two evaluations per interval, one in the last.
    #[default]
    Heun,
    /// Euler (first order): one evaluation per interval.
    Euler,
}

/// The Heun (or Euler) sampler of one scene as a state machine, so that a scheduler can
/// interleave the network evaluations of many scenes at different flow times:
/// [`Sampler::query`] says what to evaluate next, [`Sampler::advance`] takes the network's
/// prediction.
///
/// The time grid is `i / steps`; with Heun every interval but the last takes two evaluations,
/// the last one (Euler), so a sample costs `2 steps - 1` evaluations; with Euler every
/// interval takes one. Frame 0 starts from its own noise, is reset to `t X_0 + (1 - t) n_0`
/// after every step and to `X_0` at the end.
#[derive(Clone, Debug)]
pub struct Sampler {
    frames: usize,
    vertices: usize,
    steps: usize,
    step: usize,
    stage: Stage,
    z: Vec<f32>,
    n0: Vec<f32>,
    x0: Vec<f32>,
    noise_scale: f32,
    t_eps: f32,
    kind: SamplerKind,
}

impl Sampler {
    /// A sampler for `scene` over `frames` frames with `steps` denoising steps; `seed` fixes
    /// the starting noise (same seed, same trajectory).
    pub fn new(
        config: &PhysiConfig,
        scene: &MeshScene,
        frames: usize,
        steps: usize,
        seed: u64,
    ) -> Result<Sampler, ModelError> {
        Sampler::with_kind(config, scene, frames, steps, seed, SamplerKind::Heun)
    }

    /// [`Sampler::new`] with the integrator `kind`; the starting noise depends on `seed` only,
    /// so Heun and Euler start from the same noise.
    pub fn with_kind(
        config: &PhysiConfig,
        scene: &MeshScene,
        frames: usize,
        steps: usize,
        seed: u64,
        kind: SamplerKind,
    ) -> Result<Sampler, ModelError> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let eps: Vec<f32> = (0..frames * scene.vertices() * 3)
            .map(|_| standard_normal(&mut rng))
            .collect();
        Sampler::with_noise(config, scene, frames, steps, kind, &eps)
    }

    /// [`Sampler::with_kind`] from given standard-normal draws `eps [frames, V, 3]` instead of
    /// a seed (to reproduce a sampling run of another implementation): the starting noise is
    /// `noise_scale * eps` in the network's coordinates ([`PhysiConfig::noise_frame`]), frame
    /// 0's included.
    pub fn with_noise(
        config: &PhysiConfig,
        scene: &MeshScene,
        frames: usize,
        steps: usize,
        kind: SamplerKind,
        eps: &[f32],
    ) -> Result<Sampler, ModelError> {
        scene.validate(config)?;
        if frames < 2 || frames > config.frames {
            return Err(ModelError::InvalidInput(format!(
                "frames: {frames} outside 2..={}",
                config.frames
            )));
        }
        if steps == 0 || steps > MAX_STEPS {
            return Err(ModelError::InvalidInput(format!(
                "steps: {steps} outside 1..={MAX_STEPS}"
            )));
        }
        let nv = scene.vertices();
        if eps.len() != frames * nv * 3 {
            return Err(ModelError::InvalidInput(format!(
                "noise: {} values for {frames} frames of {nv} vertices (expected {})",
                eps.len(),
                frames * nv * 3
            )));
        }
        if let Some(i) = eps.iter().position(|e| !e.is_finite()) {
            return Err(ModelError::InvalidInput(format!(
                "noise[{i}] is not finite"
            )));
        }
        let (scale, offset) = config.noise_frame();
        let z: Vec<f32> = eps
            .iter()
            .enumerate()
            .map(|(i, e)| config.noise_scale * e * scale[i % 3] + offset[i % 3])
            .collect();
        let n0 = z[..nv * 3].to_vec();
        let x0 = scene.positions.iter().flatten().copied().collect();
        Ok(Sampler {
            frames,
            vertices: nv,
            steps,
            step: 0,
            stage: Stage::Predict,
            z,
            n0,
            x0,
            noise_scale: config.noise_scale,
            t_eps: config.t_eps,
            kind,
        })
    }

    fn time(&self, i: usize) -> f32 {
        i as f32 / self.steps as f32
    }

    /// Frames of the trajectory being sampled.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// Denoising steps completed so far.
    pub fn step(&self) -> usize {
        self.step
    }

    /// Denoising steps in total.
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// The starting noise scale this sampler used, metres.
    pub fn noise_scale(&self) -> f32 {
        self.noise_scale
    }

    /// The integrator.
    pub fn kind(&self) -> SamplerKind {
        self.kind
    }

    /// Network evaluations a whole sample takes: `2 steps - 1` for Heun, `steps` for Euler.
    pub fn evaluations(&self) -> usize {
        match self.kind {
            SamplerKind::Heun => 2 * self.steps - 1,
            SamplerKind::Euler => self.steps,
        }
    }

    /// True when every step is done and [`Sampler::trajectory`] is the sample.
    pub fn done(&self) -> bool {
        self.step >= self.steps
    }

    /// What the network must evaluate next: the noisy trajectory `[frames, V, 3]` and its
    /// flow time. Meaningless once [`Sampler::done`].
    pub fn query(&self) -> (&[f32], f32) {
        match &self.stage {
            Stage::Predict => (&self.z, self.time(self.step)),
            Stage::Correct { .. } => (&self.z, self.time(self.step + 1)),
        }
    }

    /// Takes the network's predicted clean trajectory for the last [`Sampler::query`]; returns
    /// true when this completed a denoising step.
    pub fn advance(&mut self, x_hat: &[f32]) -> Result<bool, ModelError> {
        if self.done() {
            return Err(ModelError::InvalidInput(
                "the sampler is already done".into(),
            ));
        }
        if x_hat.len() != self.z.len() {
            return Err(ModelError::InvalidInput(format!(
                "prediction holds {} values, expected {}",
                x_hat.len(),
                self.z.len()
            )));
        }
        let (t0, t1) = (self.time(self.step), self.time(self.step + 1));
        let dt = t1 - t0;
        let last = self.step + 1 == self.steps || self.kind == SamplerKind::Euler;
        let eps = self.t_eps;
        let velocity = |x: &[f32], z: &[f32], t: f32| -> Vec<f32> {
            let d = (1.0 - t).max(eps);
            x.iter().zip(z).map(|(x, z)| (x - z) / d).collect()
        };
        match std::mem::replace(&mut self.stage, Stage::Predict) {
            Stage::Predict => {
                let v1 = velocity(x_hat, &self.z, t0);
                if last {
                    for (z, v) in self.z.iter_mut().zip(&v1) {
                        *z += dt * v;
                    }
                } else {
                    let z_prev = self.z.clone();
                    for (z, v) in self.z.iter_mut().zip(&v1) {
                        *z += dt * v;
                    }
                    self.stage = Stage::Correct { z_prev, v1 };
                    return Ok(false);
                }
            }
            Stage::Correct { z_prev, v1 } => {
                let v2 = velocity(x_hat, &self.z, t1);
                for (i, z) in self.z.iter_mut().enumerate() {
                    *z = z_prev[i] + dt * 0.5 * (v1[i] + v2[i]);
                }
            }
        }
        self.step += 1;
        let n = self.vertices * 3;
        if self.done() {
            self.z[..n].copy_from_slice(&self.x0);
        } else {
            let t = self.time(self.step);
            for i in 0..n {
                self.z[i] = t * self.x0[i] + (1.0 - t) * self.n0[i];
            }
        }
        Ok(true)
    }

    /// The current trajectory `[frames, V, 3]`; the sample once [`Sampler::done`].
    pub fn trajectory(&self) -> &[f32] {
        &self.z
    }
}

/// Largest accepted number of denoising steps.
pub const MAX_STEPS: usize = 1000;

impl PhysiFormer {
    /// Samples one trajectory per `(scene, frames)` with `steps` Heun steps, all scenes
    /// evaluated together; scene `i` uses seed `seed + i`. Returns `[frames, V, 3]` per scene.
    pub fn sample(
        &self,
        scenes: &[(&MeshScene, usize)],
        steps: usize,
        seed: u64,
    ) -> Result<Vec<Vec<f32>>, ModelError> {
        let mut samplers = scenes
            .iter()
            .enumerate()
            .map(|(i, (s, f))| Sampler::new(&self.config, s, *f, steps, seed + i as u64))
            .collect::<Result<Vec<_>, _>>()?;
        let prepared = scenes
            .iter()
            .map(|(s, f)| self.prepare(s, *f))
            .collect::<Result<Vec<_>, _>>()?;
        while samplers.first().is_some_and(|s| !s.done()) {
            let preds = {
                let items: Vec<PreparedItem<'_>> = samplers
                    .iter()
                    .zip(&prepared)
                    .map(|(s, scene)| {
                        let (z, t) = s.query();
                        PreparedItem { scene, z, t }
                    })
                    .collect();
                self.denoise_prepared(&items)?
            };
            for (s, p) in samplers.iter_mut().zip(&preds) {
                s.advance(p)?;
            }
        }
        Ok(samplers.into_iter().map(|s| s.z).collect())
    }
}
