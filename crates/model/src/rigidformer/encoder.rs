//! Point encoder: a shared point MLP, a set-abstraction level over farthest-point-sampled
//! centres (nearest neighbours, MLP on `[neighbour - centre, feature]`, max-pool) and a second
//! level pooling the centres into one token per object.

use candle_core::{Device, Tensor};

use super::batch::BatchInputs;
use super::messages::ContactMessages;
use super::{host_index, host_tensor};
use crate::kernels::activation::silu_inference;
use crate::kernels::grouped_mlp::GroupedMlp;
use crate::layers::{Exec, Linear, Mlp, ParamStore};
use crate::{ModelConfig, ModelError};

/// Name of the encoder's first weight matrix, `[point_dim, features]`: the only parameter
/// whose shape depends on the number of per-point input features.
pub(crate) const POINT_INPUT_WEIGHT: &str = "encoder.point.0.weight";

/// The encoder's layers (`encoder.*` parameters).
pub(crate) struct Encoder {
    point: Mlp,
    sa1: Mlp,
    sa2: Mlp,
    token: Linear,
    sa_centres: usize,
    sa_neighbours: usize,
    features: usize,
}

impl Encoder {
    /// Creates or loads the encoder's parameters for configuration `c`.
    pub fn new(p: &mut ParamStore, c: &ModelConfig) -> Result<Encoder, ModelError> {
        let (c1, c2, d) = (c.point_dim, c.sa_dim, c.width);
        Ok(Encoder {
            point: Mlp::new(p, "encoder.point", c.point_features(), c1, c1)?,
            sa1: Mlp::new(p, "encoder.sa1", c1 + 3, c2, c2)?,
            sa2: Mlp::new(p, "encoder.sa2", c2 + 3, d, d)?,
            token: p.linear("encoder.token", d, d, true)?,
            sa_centres: c.sa_centres,
            sa_neighbours: c.sa_neighbours,
            features: c.point_features(),
        })
    }

    /// Per-point features `[P, C1]` (packed, no padding rows) and object tokens `[O, D]`.
    /// With `messages`, each point's feature has its contact message added before the set
    /// abstraction, and the features returned are those.
    pub fn forward(
        &self,
        inp: &BatchInputs,
        device: &Device,
        exec: Exec,
        messages: Option<&ContactMessages>,
    ) -> Result<(Tensor, Tensor), ModelError> {
        let fused = exec.fused;
        let (o, s, g) = (inp.o, self.sa_centres, self.sa_neighbours);
        let graph = inp.pose_inputs.as_ref();
        let feats = match graph {
            Some(g) => g.feats.clone(),
            None => host_tensor(device, &inp.feats, &[inp.points, self.features])?,
        };
        if exec.fused_inference() && device.is_cpu() && graph.is_none() {
            return self.forward_cpu_inference(inp, &feats, messages);
        }
        let h = self.point.forward(&feats, fused)?; // [P, C1]
        let h = match messages {
            Some(m) => m.forward(inp, &h)?,
            None => h,
        };
        let grouped = h.index_select(&host_index(device, &inp.group_idx)?, 0)?; // [O*S*G, C1]
        let rel = match graph {
            Some(g) => g.group_rel.clone(),
            None => host_tensor(device, &inp.group_rel, &[o * s * g, 3])?,
        };
        let x = Tensor::cat(&[rel, grouped], 1)?;
        let x = self.sa1.forward_max_pool(&x, g, fused)?; // [O*S, C2]
        let crel = match graph {
            Some(g) => g.centre_rel.clone(),
            None => host_tensor(device, &inp.centre_rel, &[o * s, 3])?,
        };
        let x = Tensor::cat(&[crel, x], 1)?;
        let x = self.sa2.forward_max_pool(&x, s, fused)?; // [O, D]
        let x = if exec.fused_inference() {
            silu_inference(&x)?
        } else {
            x.silu()?
        };
        let tokens = self.token.forward(&x)?;
        Ok((h, tokens))
    }

    /// [`Encoder::forward`] for inference on the CPU: the point MLP and both set-abstraction
    /// levels as [`GroupedMlp`] passes (gather, MLP and pooling per block of rows, no
    /// intermediate tensors); the same values as the composition within float rounding.
    fn forward_cpu_inference(
        &self,
        inp: &BatchInputs,
        feats: &Tensor,
        messages: Option<&ContactMessages>,
    ) -> Result<(Tensor, Tensor), ModelError> {
        let point = self.point.host_weights()?;
        let h = feats.apply_op1_no_bwd(&GroupedMlp {
            mlp: &point,
            index: None,
            lead: &[],
            lead_dim: 0,
            group: 1,
        })?; // [P, C1]
        let h = match messages {
            Some(m) => m.forward(inp, &h)?,
            None => h,
        };
        let sa1 = self.sa1.host_weights()?;
        let x = h.apply_op1_no_bwd(&GroupedMlp {
            mlp: &sa1,
            index: Some(&inp.group_idx),
            lead: &inp.group_rel,
            lead_dim: 3,
            group: self.sa_neighbours,
        })?; // [O*S, C2]
        let sa2 = self.sa2.host_weights()?;
        let x = x.apply_op1_no_bwd(&GroupedMlp {
            mlp: &sa2,
            index: None,
            lead: &inp.centre_rel,
            lead_dim: 3,
            group: self.sa_centres,
        })?; // [O, D]
        let tokens = self.token.forward(&silu_inference(&x)?)?;
        Ok((h, tokens))
    }
}
