//! The object state summary's path into the decoder: a two-layer MLP from the
//! [`OBJECT_SUMMARY_FEATURES`] numbers of [`super::features::object_summary`] to a vector added
//! to each object's token (`summary.*` parameters). Its last layer starts at zero, so a model
//! gains the summary as the same function it was and training moves it from there.

use candle_core::{Device, Tensor};

use super::host_tensor;
use super::inputs::BatchInputs;
use crate::config::OBJECT_SUMMARY_FEATURES;
use crate::layers::{Exec, Linear, ParamStore};
use crate::{ModelConfig, ModelError};

/// Names of the summary's parameters, in creation order.
pub(crate) const SUMMARY_PARAMETERS: [&str; 4] = [
    "summary.0.weight",
    "summary.0.bias",
    "summary.1.weight",
    "summary.1.bias",
];

/// The summary MLP (`summary.0`: `[D, OBJECT_SUMMARY_FEATURES]`, `summary.1`: `[D, D]`).
pub(crate) struct SummaryMlp {
    first: Linear,
    last: Linear,
}

impl SummaryMlp {
    /// Creates or loads the parameters for configuration `c`; `None` when the model has no
    /// summary. The last layer is initialised to zero.
    pub fn new(p: &mut ParamStore, c: &ModelConfig) -> Result<Option<SummaryMlp>, ModelError> {
        if !c.dynamics.object_summary {
            return Ok(None);
        }
        Ok(Some(SummaryMlp {
            first: p.linear("summary.0", OBJECT_SUMMARY_FEATURES, c.width, true)?,
            last: p.linear_init("summary.1", c.width, c.width, true, 0.0)?,
        }))
    }

    /// `tokens [O, D]` plus the MLP of the batch's summaries `[O, OBJECT_SUMMARY_FEATURES]`.
    pub fn add_to(
        &self,
        inp: &BatchInputs,
        tokens: &Tensor,
        device: &Device,
        exec: Exec,
    ) -> Result<Tensor, ModelError> {
        let s = host_tensor(
            device,
            &inp.object_summary,
            &[inp.o, OBJECT_SUMMARY_FEATURES],
        )?;
        let h = self.first.forward_silu(&s, exec.fused)?;
        Ok((tokens + self.last.forward(&h)?)?)
    }
}
