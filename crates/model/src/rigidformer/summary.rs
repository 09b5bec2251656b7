//! The per-object summaries' paths into the decoder: for each summary the model reads (the
//! object state summary of [`super::features::object_summary`], the contact summary of
//! [`super::features::contact_summary`]), a two-layer MLP from its numbers to a vector added to
//! each object's token. Its last layer starts at zero, so a model gains a summary as the same
//! function it was and training moves it from there.

use candle_core::{Device, Tensor};

use super::batch::BatchInputs;
use super::host_tensor;
use crate::config::{CONTACT_SUMMARY_FEATURES, ModelUnit, OBJECT_SUMMARY_FEATURES};
use crate::layers::{Exec, Linear, ParamStore};
use crate::{ModelConfig, ModelError};

/// A per-object summary a model may read, each with its own MLP: the summary units of
/// [`ModelUnit`], with what their MLPs need.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Summary {
    /// [`ModelUnit::ObjectSummary`]; parameters `summary.*`.
    Object,
    /// [`ModelUnit::ContactSummary`]; parameters `contact_summary.*`.
    Contact,
}

impl Summary {
    /// Every summary, in the order their parameters are created.
    const ALL: [Summary; 2] = [Summary::Object, Summary::Contact];

    /// The unit whose switch turns it on.
    fn unit(self) -> ModelUnit {
        match self {
            Summary::Object => ModelUnit::ObjectSummary,
            Summary::Contact => ModelUnit::ContactSummary,
        }
    }

    /// Numbers per object.
    fn features(self) -> usize {
        match self {
            Summary::Object => OBJECT_SUMMARY_FEATURES,
            Summary::Contact => CONTACT_SUMMARY_FEATURES,
        }
    }

    /// Prefix of its parameters' names.
    fn prefix(self) -> &'static str {
        match self {
            Summary::Object => "summary",
            Summary::Contact => "contact_summary",
        }
    }

    /// The batch's values of it, `[o, features]`.
    fn values<'a>(self, inp: &'a BatchInputs) -> &'a [f32] {
        match self {
            Summary::Object => &inp.object_summary,
            Summary::Contact => &inp.contact_summary,
        }
    }
}

/// One summary's MLP (`<prefix>.0`: `[D, features]`, `<prefix>.1`: `[D, D]`).
pub(crate) struct SummaryMlp {
    kind: Summary,
    first: Linear,
    last: Linear,
}

impl SummaryMlp {
    /// Creates or loads the parameters of every summary configuration `c` reads, in
    /// [`Summary::ALL`] order. Each last layer is initialised to zero.
    pub fn all(p: &mut ParamStore, c: &ModelConfig) -> Result<Vec<SummaryMlp>, ModelError> {
        let mut out = Vec::new();
        for kind in Summary::ALL {
            if !kind.unit().enabled(&c.dynamics) {
                continue;
            }
            let pre = kind.prefix();
            out.push(SummaryMlp {
                kind,
                first: p.linear(&format!("{pre}.0"), kind.features(), c.width, true)?,
                last: p.linear_init(&format!("{pre}.1"), c.width, c.width, true, 0.0)?,
            });
        }
        Ok(out)
    }

    /// `tokens [O, D]` plus the MLP of the batch's summaries `[O, features]`.
    pub fn add_to(
        &self,
        inp: &BatchInputs,
        tokens: &Tensor,
        device: &Device,
        exec: Exec,
    ) -> Result<Tensor, ModelError> {
        let graph = inp.pose_inputs.as_ref().and_then(|g| match self.kind {
            Summary::Object => g.object_summary.clone(),
            Summary::Contact => None,
        });
        let s = match graph {
            Some(s) => s,
            None => host_tensor(
                device,
                self.kind.values(inp),
                &[inp.o, self.kind.features()],
            )?,
        };
        let h = self.first.forward_silu(&s, exec.fused)?;
        Ok((tokens + self.last.forward(&h)?)?)
    }
}
