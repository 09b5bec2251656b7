//! Learning-rate schedule, global gradient-norm clipping and AdamW with per-parameter weight
//! decay (candle's `AdamW` decays every variable and cannot clip, so this is written here).

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use candle_core::backprop::GradStore;
use candle_core::{DType, Tensor, Var};

use super::TrainError;
use super::config::OptimConfig;

/// Learning rate at iteration `step` (0-based): linear warm-up from `warmup_start * lr` to `lr`
/// over `warmup` iterations, then cosine decay to `min_lr_ratio * lr` at `iterations`
/// (constant afterwards).
pub fn learning_rate(c: &OptimConfig, step: u64) -> f64 {
    if step < c.warmup {
        let f = step as f64 / c.warmup as f64;
        return c.lr * (c.warmup_start + (1.0 - c.warmup_start) * f);
    }
    let span = c.iterations.saturating_sub(c.warmup).max(1) as f64;
    let f = ((step - c.warmup) as f64 / span).min(1.0);
    let cos = 0.5 * (1.0 + (std::f64::consts::PI * f).cos());
    c.lr * (c.min_lr_ratio + (1.0 - c.min_lr_ratio) * cos)
}

/// One trainable parameter with its AdamW state.
struct Slot {
    name: String,
    var: Var,
    m: Tensor,
    v: Tensor,
    ema: Option<Tensor>,
    decay: bool,
    /// Multiple of the schedule's learning rate this parameter trains at.
    lr_scale: f64,
}

/// AdamW (decoupled weight decay, bias-corrected moments) over named variables, with a global
/// gradient-norm clip and an optional exponential moving average of the weights.
pub struct AdamW {
    slots: Vec<Slot>,
    /// Number of updates applied so far.
    pub t: u64,
}

/// What one update did.
#[derive(Clone, Copy, Debug)]
pub struct UpdateStats {
    /// Global L2 norm of the gradient before clipping.
    pub grad_norm: f64,
    /// Factor the gradient was multiplied by (1 when not clipped).
    pub clip_scale: f64,
}

impl AdamW {
    /// Optimiser state for `vars` (name -> variable), sorted by name for a stable order.
    /// `no_decay(name)` selects parameters without weight decay; `ema` keeps a weight average.
    pub fn new(
        vars: &HashMap<String, Var>,
        no_decay: impl Fn(&str) -> bool,
        ema: bool,
    ) -> Result<AdamW, TrainError> {
        let mut names: Vec<&String> = vars.keys().collect();
        names.sort();
        let mut slots = Vec::with_capacity(names.len());
        for name in names {
            let var = vars[name].clone();
            let z = var.as_tensor().zeros_like()?;
            slots.push(Slot {
                name: name.clone(),
                decay: !no_decay(name),
                m: z.clone(),
                v: z,
                ema: if ema {
                    Some(var.as_tensor().copy()?.detach())
                } else {
                    None
                },
                var,
                lr_scale: 1.0,
            });
        }
        Ok(AdamW { slots, t: 0 })
    }

    /// Sets each parameter's learning-rate factor from `scales` (name prefix -> factor; the
    /// longest matching prefix wins, 1 where none matches). Errors on a prefix that matches no
    /// parameter, which would otherwise be a silent typo.
    pub fn with_lr_scale(mut self, scales: &BTreeMap<String, f64>) -> Result<AdamW, TrainError> {
        for prefix in scales.keys() {
            if !self
                .slots
                .iter()
                .any(|s| s.name.starts_with(prefix.as_str()))
            {
                return Err(TrainError::Config(format!(
                    "optim.lr_scale: no parameter name starts with {prefix:?}"
                )));
            }
        }
        for s in &mut self.slots {
            s.lr_scale = scales
                .iter()
                .filter(|(p, _)| s.name.starts_with(p.as_str()))
                .max_by_key(|(p, _)| p.len())
                .map_or(1.0, |(_, f)| *f);
        }
        Ok(self)
    }

    /// Names of the parameters that receive weight decay.
    pub fn decayed(&self) -> Vec<&str> {
        self.slots
            .iter()
            .filter(|s| s.decay)
            .map(|s| s.name.as_str())
            .collect()
    }

    /// Global L2 norm of the gradients of all parameters (missing gradients count as zero).
    pub fn grad_norm(&self, grads: &GradStore) -> Result<f64, TrainError> {
        let mut sum = 0f64;
        for s in &self.slots {
            if let Some(g) = grads.get(s.var.as_tensor()) {
                sum += g
                    .sqr()?
                    .sum_all()?
                    .to_dtype(DType::F64)?
                    .to_scalar::<f64>()?;
            }
        }
        Ok(sum.sqrt())
    }

    /// One AdamW step at learning rate `lr` (times each parameter's factor,
    /// [`AdamW::with_lr_scale`]): clips the gradient to global norm `c.grad_clip` (when > 0),
    /// updates the moments, applies decoupled weight decay to decayed parameters
    /// and updates the weight average with `c.ema_decay`. A non-finite gradient norm skips the
    /// update and is reported as an error.
    pub fn step(
        &mut self,
        grads: &GradStore,
        lr: f64,
        c: &OptimConfig,
    ) -> Result<UpdateStats, TrainError> {
        let grad_norm = self.grad_norm(grads)?;
        if !grad_norm.is_finite() {
            return Err(TrainError::NonFinite(format!(
                "gradient norm is {grad_norm} at update {}",
                self.t + 1
            )));
        }
        let clip_scale = if c.grad_clip > 0.0 && grad_norm > c.grad_clip {
            c.grad_clip / (grad_norm + 1e-12)
        } else {
            1.0
        };
        self.t += 1;
        let t = self.t as i32;
        let bc1 = 1.0 - c.beta1.powi(t);
        let bc2 = 1.0 - c.beta2.powi(t);
        for s in &mut self.slots {
            let Some(g) = grads.get(s.var.as_tensor()) else {
                continue;
            };
            let g = (g * clip_scale)?.detach();
            s.m = ((&s.m * c.beta1)? + (&g * (1.0 - c.beta1))?)?.detach();
            s.v = ((&s.v * c.beta2)? + (g.sqr()? * (1.0 - c.beta2))?)?.detach();
            let mhat = (&s.m / bc1)?;
            let vhat = (&s.v / bc2)?;
            let update = (mhat / (vhat.sqrt()? + c.eps)?)?;
            let lr = lr * s.lr_scale;
            let w = &s.var.as_tensor().detach();
            let w = if s.decay && c.weight_decay > 0.0 {
                (w * (1.0 - lr * c.weight_decay))?
            } else {
                w.clone()
            };
            let new = (w - (update * lr)?)?;
            s.var.set(&new)?;
        }
        if c.ema_decay > 0.0 {
            // Warm-started average: the effective decay grows from 0 so early weights fade.
            let d = c
                .ema_decay
                .min((1.0 + self.t as f64) / (10.0 + self.t as f64));
            for s in &mut self.slots {
                if let Some(e) = &s.ema {
                    s.ema = Some(((e * d)? + (s.var.as_tensor() * (1.0 - d))?)?.detach());
                }
            }
        }
        Ok(UpdateStats {
            grad_norm,
            clip_scale,
        })
    }

    /// Sharpness-aware minimisation's ascent: moves every parameter by `rho * g / |g|` (`|g|`
    /// the global L2 norm of `grads` over all parameters; parameters without a gradient stay)
    /// and returns the weights as they were, for [`AdamW::restore`]. A non-finite gradient
    /// norm moves nothing and is reported as an error.
    pub fn perturb(&self, grads: &GradStore, rho: f64) -> Result<Vec<Tensor>, TrainError> {
        let norm = self.grad_norm(grads)?;
        if !norm.is_finite() {
            return Err(TrainError::NonFinite(format!(
                "gradient norm is {norm} before update {}",
                self.t + 1
            )));
        }
        let scale = rho / (norm + 1e-12);
        let mut saved = Vec::with_capacity(self.slots.len());
        for s in &self.slots {
            let w = s.var.as_tensor().copy()?.detach();
            if let Some(g) = grads.get(s.var.as_tensor()) {
                s.var.set(&(&w + (g * scale)?)?)?;
            }
            saved.push(w);
        }
        Ok(saved)
    }

    /// Sets every parameter back to the weights [`AdamW::perturb`] returned.
    pub fn restore(&self, saved: Vec<Tensor>) -> Result<(), TrainError> {
        for (s, w) in self.slots.iter().zip(saved) {
            s.var.set(&w)?;
        }
        Ok(())
    }

    /// Copies of the averaged weights by name (the raw weights when no average is kept).
    pub fn ema_weights(&self) -> Result<HashMap<String, Tensor>, TrainError> {
        let mut out = HashMap::new();
        for s in &self.slots {
            let t = match &s.ema {
                Some(e) => e.clone(),
                None => s.var.as_tensor().copy()?,
            };
            out.insert(s.name.clone(), t);
        }
        Ok(out)
    }

    /// Writes moments, weight averages and the update count to a safetensors file.
    pub fn save(&self, path: &Path) -> Result<(), TrainError> {
        let mut map = HashMap::new();
        for s in &self.slots {
            map.insert(format!("m.{}", s.name), s.m.clone());
            map.insert(format!("v.{}", s.name), s.v.clone());
            if let Some(e) = &s.ema {
                map.insert(format!("ema.{}", s.name), e.clone());
            }
        }
        let t = self.t as f64;
        map.insert(
            "t".into(),
            Tensor::new(&[t], &candle_core::Device::Cpu)?.to_dtype(DType::F64)?,
        );
        dynaserve_model::save_tensors(&map, path)?;
        Ok(())
    }

    /// Restores the state written by [`AdamW::save`]; every parameter must be present with the
    /// same shape.
    pub fn load(&mut self, path: &Path) -> Result<(), TrainError> {
        let dev = self
            .slots
            .first()
            .map(|s| s.var.device().clone())
            .unwrap_or(candle_core::Device::Cpu);
        let map = candle_core::safetensors::load(path, &dev)?;
        let get = |k: &str, like: &Tensor| -> Result<Tensor, TrainError> {
            let t = map.get(k).ok_or_else(|| {
                TrainError::Config(format!("{}: optimizer state lacks {k}", path.display()))
            })?;
            if t.dims() != like.dims() {
                return Err(TrainError::Config(format!(
                    "{}: {k} has shape {:?}, expected {:?}",
                    path.display(),
                    t.dims(),
                    like.dims()
                )));
            }
            Ok(t.to_dtype(like.dtype())?)
        };
        for s in &mut self.slots {
            s.m = get(&format!("m.{}", s.name), &s.m)?;
            s.v = get(&format!("v.{}", s.name), &s.v)?;
            if let Some(e) = &s.ema {
                s.ema = Some(get(&format!("ema.{}", s.name), e)?);
            }
        }
        let t = map
            .get("t")
            .ok_or_else(|| TrainError::Config(format!("{}: no update count", path.display())))?;
        self.t = t.to_vec1::<f64>()?[0] as u64;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    #[test]
    fn the_sharpness_ascent_moves_rho_along_the_gradient_and_restores_exactly() {
        let w = Var::new(&[1.0f32, 2.0, 3.0], &Device::Cpu).unwrap();
        let b = Var::new(&[5.0f32], &Device::Cpu).unwrap();
        let vars = HashMap::from([("w".to_string(), w.clone()), ("b".to_string(), b.clone())]);
        let opt = AdamW::new(&vars, |_| false, false).unwrap();
        // Loss 3 w0 + 4 w1 (b unused): gradient (3, 4, 0), norm 5.
        let loss = (w.as_tensor() * &Tensor::new(&[3.0f32, 4.0, 0.0], &Device::Cpu).unwrap())
            .unwrap()
            .sum_all()
            .unwrap();
        let grads = loss.backward().unwrap();
        let saved = opt.perturb(&grads, 0.5).unwrap();
        let moved = w.as_tensor().to_vec1::<f32>().unwrap();
        for (m, want) in moved.iter().zip([1.3f32, 2.4, 3.0]) {
            assert!((m - want).abs() < 1e-6, "{moved:?}");
        }
        assert_eq!(b.as_tensor().to_vec1::<f32>().unwrap(), [5.0]);
        opt.restore(saved).unwrap();
        assert_eq!(w.as_tensor().to_vec1::<f32>().unwrap(), [1.0, 2.0, 3.0]);
    }

    #[test]
    fn schedule_warms_up_then_decays() {
        let c = OptimConfig {
            lr: 1.0,
            warmup: 10,
            iterations: 110,
            warmup_start: 0.1,
            min_lr_ratio: 0.0,
            ..OptimConfig::default()
        };
        assert!((learning_rate(&c, 0) - 0.1).abs() < 1e-12);
        assert!((learning_rate(&c, 5) - 0.55).abs() < 1e-12);
        assert!((learning_rate(&c, 10) - 1.0).abs() < 1e-12);
        assert!((learning_rate(&c, 60) - 0.5).abs() < 1e-12);
        assert!(learning_rate(&c, 110).abs() < 1e-12);
        assert!(learning_rate(&c, 500).abs() < 1e-12);
    }

    #[test]
    fn clipping_and_decay_follow_the_formulas() {
        // Loss = sum(3 * w) for a decayed w and a bias b: gradient 3 everywhere, norm 3*sqrt(4).
        let w = Var::new(&[1.0f32, 2.0, 3.0], &Device::Cpu).unwrap();
        let b = Var::new(&[1.0f32], &Device::Cpu).unwrap();
        let vars = HashMap::from([
            ("l.weight".to_string(), w.clone()),
            ("l.bias".into(), b.clone()),
        ]);
        let mut opt = AdamW::new(&vars, |n| n.ends_with(".bias"), false).unwrap();
        assert_eq!(opt.decayed(), vec!["l.weight"]);
        let loss = ((w.as_tensor().sum_all().unwrap() + b.as_tensor().sum_all().unwrap()).unwrap()
            * 3.0)
            .unwrap();
        let grads = loss.backward().unwrap();
        let c = OptimConfig {
            weight_decay: 0.5,
            grad_clip: 1.0,
            ema_decay: 0.0,
            ..OptimConfig::default()
        };
        let st = opt.step(&grads, 0.1, &c).unwrap();
        assert!((st.grad_norm - 6.0).abs() < 1e-6);
        assert!((st.clip_scale - 1.0 / 6.0).abs() < 1e-6);
        // First Adam step moves every weight by lr * sign(g) (bias-corrected), plus decay.
        let wv = w.as_tensor().to_vec1::<f32>().unwrap();
        for (i, x0) in [1.0f32, 2.0, 3.0].iter().enumerate() {
            let expect = x0 * (1.0 - 0.1 * 0.5) - 0.1;
            assert!((wv[i] - expect).abs() < 1e-5, "{} vs {expect}", wv[i]);
        }
        let bv = b.as_tensor().to_vec1::<f32>().unwrap()[0];
        assert!((bv - 0.9).abs() < 1e-5);
    }

    /// A parameter under an `lr_scale` prefix moves that multiple of the others' first Adam
    /// step (lr * sign(g)); the longest prefix wins; a prefix naming no parameter is refused.
    #[test]
    fn lr_scale_multiplies_the_step_of_matching_parameters() {
        let vars: HashMap<String, Var> = ["a.weight", "new.0.weight", "new.1.weight"]
            .iter()
            .map(|n| (n.to_string(), Var::new(&[0.0f32], &Device::Cpu).unwrap()))
            .collect();
        let scales = BTreeMap::from([("new.".to_string(), 10.0), ("new.1.".to_string(), 3.0)]);
        let mut opt = AdamW::new(&vars, |_| false, false)
            .unwrap()
            .with_lr_scale(&scales)
            .unwrap();
        let loss = vars
            .values()
            .map(|v| v.as_tensor().sum_all().unwrap())
            .reduce(|a, b| (a + b).unwrap())
            .unwrap();
        let grads = loss.backward().unwrap();
        let c = OptimConfig {
            weight_decay: 0.0,
            grad_clip: 0.0,
            ema_decay: 0.0,
            ..OptimConfig::default()
        };
        opt.step(&grads, 0.01, &c).unwrap();
        let moved = |n: &str| -vars[n].as_tensor().to_vec1::<f32>().unwrap()[0];
        assert!((moved("a.weight") - 0.01).abs() < 1e-6);
        assert!((moved("new.0.weight") - 0.1).abs() < 1e-6);
        assert!((moved("new.1.weight") - 0.03).abs() < 1e-6);
        let typo = BTreeMap::from([("nwe.".to_string(), 10.0)]);
        let err = AdamW::new(&vars, |_| false, false)
            .unwrap()
            .with_lr_scale(&typo)
            .err()
            .unwrap();
        assert!(err.to_string().contains("nwe."), "{err}");
    }
}
