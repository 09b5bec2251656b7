//! Contact messages ([`crate::DynamicsConfig::contact_messages`]): every point in contact with
//! another object receives a message from the point its contact search found there, and adds
//! it to its own feature before the set abstraction.
//!
//! Without them two objects meet only as whole-object tokens in the decoder's attention, and a
//! point's inputs describe the surface it touches (gap, velocity, normal) but not where on the
//! other body that surface lies. A collision's exchange depends on both lever arms: the impulse
//! between two bodies is divided by an effective mass with a term `(r_a x n) . I_a^-1 (r_a x n)`
//! for each body. The message is computed from both points' encoder features and both lever
//! arms, so the network can form that pairwise quantity at the contact itself.
//!
//! The partner rows and lever arms are found on the host per step
//! (`ObjectContext::partners` in `inputs`); the forward pass ([`ContactMessages::forward`])
//! is candle ops, differentiable in both points' features.

use candle_core::{Device, Tensor};

use super::batch::BatchInputs;
use super::{host_index, host_tensor};
use crate::layers::{Linear, ParamStore};
use crate::{ModelConfig, ModelError};

/// Hidden width of the message MLP.
pub(crate) const MESSAGE_HIDDEN: usize = 64;

/// Numbers of geometry per message: the receiving point's lever arm, then its partner's.
pub(crate) const MESSAGE_GEOMETRY: usize = 6;

/// The unit's layers (`messages.*` parameters): the receiving point's feature (`C1 -> H`), the
/// partner's (`C1 -> H`, no bias), both lever arms (`6 -> H`, no bias), and an output layer
/// (`H -> C1`, starting at zero, so a model gains the unit as the same function).
pub(crate) struct ContactMessages {
    own: Linear,
    partner: Linear,
    levers: Linear,
    out: Linear,
    device: Device,
}

impl ContactMessages {
    /// Creates or loads the unit's parameters for configuration `c`.
    pub fn new(
        p: &mut ParamStore,
        c: &ModelConfig,
        device: &Device,
    ) -> Result<ContactMessages, ModelError> {
        Ok(ContactMessages {
            own: p.linear("messages.own", c.point_dim, MESSAGE_HIDDEN, true)?,
            partner: p.linear("messages.partner", c.point_dim, MESSAGE_HIDDEN, false)?,
            levers: p.linear("messages.levers", MESSAGE_GEOMETRY, MESSAGE_HIDDEN, false)?,
            out: p.linear_init("messages.out", MESSAGE_HIDDEN, c.point_dim, true, 0.0)?,
            device: device.clone(),
        })
    }

    /// The packed point features `h` (`[P, C1]`) with every message added: `h_i + m_i`, with
    /// `m_i = W_out silu(W_own h_i + W_partner h_j + W_levers [r_i, r_j])` for each point `i`
    /// with a contact partner `j` ([`BatchInputs::contact_rows`]); the other rows unchanged.
    pub fn forward(&self, inp: &BatchInputs, h: &Tensor) -> Result<Tensor, ModelError> {
        let (device, n) = (&self.device, inp.contact_rows.len());
        if inp.partner_row.len() != n || inp.partner_levers.len() != n * MESSAGE_GEOMETRY {
            return Err(ModelError::Internal(
                "contact messages: the batch's contact partners are malformed".into(),
            ));
        }
        if n == 0 {
            return Ok(h.clone());
        }
        let rows = host_index(device, &inp.contact_rows)?;
        let own = h.index_select(&rows, 0)?; // [Pc, C1]
        let partner = h.index_select(&host_index(device, &inp.partner_row)?, 0)?; // [Pc, C1]
        let levers = host_tensor(device, &inp.partner_levers, &[n, MESSAGE_GEOMETRY])?;
        let hidden = ((self.own.forward(&own)? + self.partner.forward(&partner)?)?
            + self.levers.forward(&levers)?)?;
        let message = self.out.forward(&hidden.silu()?)?; // [Pc, C1]
        Ok(h.index_add(&rows, &message, 0)?)
    }
}
