//! Parameter store: random initialisation or checkpoint loading, every parameter registered
//! by name in a [`VarMap`] (names and shapes are the checkpoint format).

use std::collections::{BTreeSet, HashMap};

use candle_core::{DType, Device, Tensor, Var};
use candle_nn::VarMap;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::{Linear, RmsNorm};
use crate::ModelError;

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

    /// True when the parameters are training variables.
    pub fn trainable(&self) -> bool {
        self.trainable
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
        Ok(Linear::new(w, b))
    }

    /// An RMSNorm over the last dimension of width `dim` (scale initialised to 1).
    pub fn rms_norm(&mut self, name: &str, dim: usize, eps: f32) -> Result<RmsNorm, ModelError> {
        let alpha = self.get(&format!("{name}.weight"), &[dim], Init::Const(1.0))?;
        Ok(RmsNorm { alpha, eps })
    }
}
