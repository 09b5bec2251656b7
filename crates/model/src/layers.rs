//! Parameter store (random initialisation or checkpoint loading) and the small layers the
//! networks are built from. Every layer takes a [`Mode`]: inference may use candle's fused
//! kernels, training must use the gradient-carrying compositions (fused `softmax_last_dim` and
//! `rms_norm` silently drop gradients in candle 0.11).

use std::collections::{BTreeSet, HashMap};

use candle_core::{D, DType, Device, Tensor, Var};
use candle_nn::VarMap;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::ModelError;

/// Which kernels the forward pass uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Fast fused kernels; no gradients needed.
    Inference,
    /// Differentiable compositions only (every parameter receives its gradient).
    Training,
}

/// Softmax over the last dimension.
pub fn softmax_last(x: &Tensor, mode: Mode) -> candle_core::Result<Tensor> {
    match mode {
        Mode::Inference => candle_nn::ops::softmax_last_dim(&x.contiguous()?),
        Mode::Training => candle_nn::ops::softmax(x, D::Minus1),
    }
}

/// Initialisation of a new parameter.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Init {
    /// Uniform in `[-b, b]`.
    Uniform(f32),
    /// Every element equal to the value.
    Const(f32),
}

enum Source {
    Random(Box<ChaCha8Rng>),
    Loaded(HashMap<String, Tensor>),
}

/// Creates (random init) or takes (checkpoint) every named parameter, registering it in a
/// [`VarMap`] so that training sees it and `save` writes it.
pub(crate) struct ParamStore {
    source: Source,
    varmap: VarMap,
    device: Device,
    trainable: bool,
    used: BTreeSet<String>,
}

impl ParamStore {
    /// A store that initialises parameters from a seeded generator.
    pub fn random(seed: u64, device: &Device, trainable: bool) -> ParamStore {
        ParamStore {
            source: Source::Random(Box::new(ChaCha8Rng::seed_from_u64(seed))),
            varmap: VarMap::new(),
            device: device.clone(),
            trainable,
            used: BTreeSet::new(),
        }
    }

    /// A store that takes parameters from loaded tensors (any float dtype; converted to f32).
    pub fn loaded(
        tensors: HashMap<String, Tensor>,
        device: &Device,
        trainable: bool,
    ) -> ParamStore {
        ParamStore {
            source: Source::Loaded(tensors),
            varmap: VarMap::new(),
            device: device.clone(),
            trainable,
            used: BTreeSet::new(),
        }
    }

    /// The parameter `name` of `shape`.
    pub fn get(&mut self, name: &str, shape: &[usize], init: Init) -> Result<Tensor, ModelError> {
        if !self.used.insert(name.to_string()) {
            return Err(ModelError::Internal(format!(
                "parameter {name} defined twice"
            )));
        }
        let t = match &mut self.source {
            Source::Random(rng) => {
                let n: usize = shape.iter().product();
                let data: Vec<f32> = match init {
                    Init::Uniform(b) => (0..n).map(|_| rng.random_range(-b..=b)).collect(),
                    Init::Const(c) => vec![c; n],
                };
                Tensor::from_vec(data, shape, &Device::Cpu)?
            }
            Source::Loaded(map) => {
                let t = map.remove(name).ok_or_else(|| {
                    ModelError::Checkpoint(format!(
                        "model.safetensors has no tensor {name:?} (expected shape {shape:?})"
                    ))
                })?;
                if t.dims() != shape {
                    return Err(ModelError::Checkpoint(format!(
                        "tensor {name:?} has shape {:?}, the configuration needs {shape:?}",
                        t.dims()
                    )));
                }
                match t.dtype() {
                    DType::F32 | DType::F16 | DType::BF16 | DType::F64 => {}
                    other => {
                        return Err(ModelError::Checkpoint(format!(
                            "tensor {name:?} has dtype {other:?}; expected a float type"
                        )));
                    }
                }
                let t = t.to_dtype(DType::F32)?;
                let values = t.flatten_all()?.to_vec1::<f32>()?;
                if values.iter().any(|v| !v.is_finite()) {
                    return Err(ModelError::Checkpoint(format!(
                        "tensor {name:?} holds non-finite values"
                    )));
                }
                t
            }
        };
        let var = Var::from_tensor(&t.to_device(&self.device)?)?;
        let tensor = if self.trainable {
            var.as_tensor().clone()
        } else {
            var.as_tensor().detach()
        };
        self.varmap
            .data()
            .lock()
            .map_err(|_| ModelError::Internal("parameter map lock poisoned".into()))?
            .insert(name.to_string(), var);
        Ok(tensor)
    }

    /// Finishes building: fails if a loaded checkpoint holds tensors the model does not use.
    pub fn finish(self) -> Result<VarMap, ModelError> {
        if let Source::Loaded(rest) = &self.source
            && !rest.is_empty()
        {
            let mut names: Vec<&String> = rest.keys().collect();
            names.sort();
            return Err(ModelError::Checkpoint(format!(
                "model.safetensors holds {} tensors this configuration does not use: {:?}",
                names.len(),
                names.iter().take(8).collect::<Vec<_>>()
            )));
        }
        Ok(self.varmap)
    }

    /// A fully connected layer `in -> out` (weights `[out, in]`, uniform `+-1/sqrt(in)`).
    pub fn linear(
        &mut self,
        name: &str,
        input: usize,
        output: usize,
        bias: bool,
    ) -> Result<Linear, ModelError> {
        self.linear_init(name, input, output, bias, 1.0 / (input as f32).sqrt())
    }

    /// A fully connected layer with weights uniform in `+-bound` and zero bias.
    pub fn linear_init(
        &mut self,
        name: &str,
        input: usize,
        output: usize,
        bias: bool,
        bound: f32,
    ) -> Result<Linear, ModelError> {
        let w = self.get(
            &format!("{name}.weight"),
            &[output, input],
            Init::Uniform(bound),
        )?;
        let b = if bias {
            Some(self.get(&format!("{name}.bias"), &[output], Init::Const(0.0))?)
        } else {
            None
        };
        Ok(Linear { w, b })
    }

    /// An RMSNorm over the last dimension of width `dim` (scale initialised to 1).
    pub fn rms_norm(&mut self, name: &str, dim: usize, eps: f32) -> Result<RmsNorm, ModelError> {
        let alpha = self.get(&format!("{name}.weight"), &[dim], Init::Const(1.0))?;
        Ok(RmsNorm { alpha, eps })
    }
}

/// `y = x W^T + b` over the last dimension of any-rank input.
#[derive(Clone, Debug)]
pub(crate) struct Linear {
    w: Tensor,
    b: Option<Tensor>,
}

impl Linear {
    pub fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let dims = x.dims().to_vec();
        let last = dims[dims.len() - 1];
        let rows = x.elem_count() / last.max(1);
        let x2 = x.reshape((rows, last))?;
        let mut y = x2.matmul(&self.w.t()?)?;
        if let Some(b) = &self.b {
            y = y.broadcast_add(b)?;
        }
        let mut out = dims;
        let n = out.len();
        out[n - 1] = self.w.dim(0)?;
        y.reshape(out)
    }
}

/// Root-mean-square normalisation with a learned scale.
#[derive(Clone, Debug)]
pub(crate) struct RmsNorm {
    alpha: Tensor,
    eps: f32,
}

impl RmsNorm {
    pub fn forward(&self, x: &Tensor, mode: Mode) -> candle_core::Result<Tensor> {
        match mode {
            Mode::Inference => candle_nn::ops::rms_norm(&x.contiguous()?, &self.alpha, self.eps),
            Mode::Training => candle_nn::ops::rms_norm_slow(x, &self.alpha, self.eps),
        }
    }
}

/// Two-layer MLP with SiLU: `in -> hidden -> out`.
#[derive(Clone, Debug)]
pub(crate) struct Mlp {
    a: Linear,
    b: Linear,
}

impl Mlp {
    pub fn new(
        p: &mut ParamStore,
        name: &str,
        input: usize,
        hidden: usize,
        output: usize,
    ) -> Result<Mlp, ModelError> {
        Ok(Mlp {
            a: p.linear(&format!("{name}.0"), input, hidden, true)?,
            b: p.linear(&format!("{name}.1"), hidden, output, true)?,
        })
    }

    pub fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        self.b.forward(&self.a.forward(x)?.silu()?)
    }
}

/// SwiGLU feed-forward: `W2 (silu(W1a x) * W1b x)`.
#[derive(Clone, Debug)]
pub(crate) struct SwiGlu {
    up: Linear,
    down: Linear,
    hidden: usize,
}

impl SwiGlu {
    pub fn new(
        p: &mut ParamStore,
        name: &str,
        dim: usize,
        hidden: usize,
    ) -> Result<SwiGlu, ModelError> {
        Ok(SwiGlu {
            up: p.linear(&format!("{name}.up"), dim, 2 * hidden, false)?,
            down: p.linear(&format!("{name}.down"), hidden, dim, false)?,
            hidden,
        })
    }

    pub fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let u = self.up.forward(x)?;
        let a = u.narrow(D::Minus1, 0, self.hidden)?;
        let b = u.narrow(D::Minus1, self.hidden, self.hidden)?;
        self.down.forward(&(a.silu()? * b)?)
    }
}

/// Rotates the first `2 * cos.dim(-1)` channels of `x` (`[B, H, T, dh]`) as even/odd pairs by
/// `(cos, sin)` (`[B, 1, T, P]`); the remaining channels pass through.
pub(crate) fn rotate_pairs(x: &Tensor, cos: &Tensor, sin: &Tensor) -> candle_core::Result<Tensor> {
    let (b, h, t, dh) = x.dims4()?;
    let p = cos.dim(D::Minus1)?;
    let rot = x.narrow(D::Minus1, 0, 2 * p)?.reshape((b, h, t, p, 2))?;
    let e = rot.narrow(D::Minus1, 0, 1)?.squeeze(D::Minus1)?;
    let o = rot.narrow(D::Minus1, 1, 1)?.squeeze(D::Minus1)?;
    let re = (e.broadcast_mul(cos)? - o.broadcast_mul(sin)?)?;
    let ro = (e.broadcast_mul(sin)? + o.broadcast_mul(cos)?)?;
    let rotated = Tensor::stack(&[re, ro], D::Minus1)?.reshape((b, h, t, 2 * p))?;
    if 2 * p == dh {
        Ok(rotated)
    } else {
        Tensor::cat(
            &[rotated, x.narrow(D::Minus1, 2 * p, dh - 2 * p)?],
            D::Minus1,
        )
    }
}

/// Elementwise Smooth L1 of `diff` with transition `beta`, averaged over all elements.
pub fn smooth_l1_mean(diff: &Tensor, beta: f32) -> candle_core::Result<Tensor> {
    let a = diff.abs()?;
    let quad = (diff.sqr()? * (0.5 / beta as f64))?;
    let lin = (&a - 0.5 * beta as f64)?;
    let small = a.lt(beta as f64)?;
    small.where_cond(&quad, &lin)?.mean_all()
}
