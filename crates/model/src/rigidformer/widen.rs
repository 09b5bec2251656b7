//! Widening a trained model: a 12-feature model becomes one that also reads the contact
//! velocity, a model without surface normals one that reads them, a model without a per-object
//! summary one that reads it, a model gets more decoder blocks, and its point encoder more
//! channels; each computes exactly the same function until training moves the new weights.

use std::collections::HashMap;

use candle_core::Tensor;

use super::RigidFormer;
use super::anchor_head::query_segments;
use super::encoder::POINT_INPUT_WEIGHT;
use crate::config::{InputGroup, ModelUnit};
use crate::layers::ParamStore;
use crate::{FeatureNormalization, ModelError};

impl RigidFormer {
    /// A copy of this model that also takes the contact velocity features
    /// ([`crate::DynamicsConfig::contact_velocity`]). The encoder's first layer gets
    /// [`crate::CONTACT_VELOCITY_FEATURES`] zero input columns, so the copy's outputs equal this
    /// model's; every other weight and the existing normalisation constants are copied, and
    /// `extra` (the new features' `mean` and `std`, 3 values each) is appended to the
    /// normalisation. `trainable` keeps gradient tracking on the copy's weights.
    ///
    /// Errors if the model already takes the contact velocity or `extra` is not 3 finite means
    /// and 3 finite positive scales.
    pub fn widened_with_contact_velocity(
        &self,
        extra: &FeatureNormalization,
        trainable: bool,
    ) -> Result<RigidFormer, ModelError> {
        self.widened_with_inputs(InputGroup::ContactVelocity, extra, trainable)
    }

    /// A copy of this model that also takes the surface normal features
    /// ([`crate::DynamicsConfig::surface_normals`]), as
    /// [`RigidFormer::widened_with_contact_velocity`] does for the contact velocity: the
    /// encoder's first layer gets [`crate::SURFACE_NORMAL_FEATURES`] zero input columns after the
    /// existing ones, so the copy's outputs equal this model's, and `extra` (7 means and 7
    /// scales) is appended to the normalisation. `trainable` keeps gradient tracking.
    ///
    /// Errors if the model already takes the surface normals or `extra` is malformed.
    pub fn widened_with_surface_normals(
        &self,
        extra: &FeatureNormalization,
        trainable: bool,
    ) -> Result<RigidFormer, ModelError> {
        self.widened_with_inputs(InputGroup::SurfaceNormals, extra, trainable)
    }

    /// A copy of this model that also takes the input `group`: zero encoder input columns and
    /// `extra`'s constants (`group.count()` means and scales) inserted at the group's place in
    /// the layout ([`InputGroup::offset`]), so the copy computes this model's function.
    /// `trainable` keeps gradient tracking on the copy's weights.
    ///
    /// Errors if the model already takes the group or `extra` is malformed.
    pub fn widened_with_inputs(
        &self,
        group: InputGroup,
        extra: &FeatureNormalization,
        trainable: bool,
    ) -> Result<RigidFormer, ModelError> {
        let what = group.name();
        if group.enabled(&self.config.dynamics) {
            return Err(ModelError::InvalidInput(format!(
                "the model already takes the {what}"
            )));
        }
        let count = group.count();
        if extra.mean.len() != count || extra.std.len() != count {
            return Err(ModelError::InvalidInput(format!(
                "{what} normalisation needs {count} means and stds, got {} and {}",
                extra.mean.len(),
                extra.std.len()
            )));
        }
        let at = group.offset(&self.config.dynamics);
        let mut config = self.config.clone();
        group.set(&mut config.dynamics, true);
        let norm = &mut config.normalization;
        norm.mean.splice(at..at, extra.mean.iter().copied());
        norm.std.splice(at..at, extra.std.iter().copied());
        config.validate()?;
        let mut tensors = self.weight_copies()?;
        let w = tensors.remove(POINT_INPUT_WEIGHT).ok_or_else(|| {
            ModelError::Internal(format!("the model has no parameter {POINT_INPUT_WEIGHT}"))
        })?;
        let zeros = Tensor::zeros((w.dim(0)?, count), w.dtype(), w.device())?;
        let (before, after) = (w.narrow(1, 0, at)?, w.narrow(1, at, w.dim(1)? - at)?);
        tensors.insert(
            POINT_INPUT_WEIGHT.to_string(),
            Tensor::cat(&[&before, &zeros, &after], 1)?.contiguous()?,
        );
        self.rebuilt(config, tensors, trainable)
    }

    /// A copy of this model with `unit` (a summary's MLP, the contact wrench, the contact
    /// messages): the unit's layers are drawn from `seed` and its last layer is zero, so the
    /// copy's outputs equal this model's; every other weight is copied. `trainable` keeps
    /// gradient tracking on the copy's weights.
    ///
    /// Errors if the model already has the unit.
    pub fn widened_with_unit(
        &self,
        unit: ModelUnit,
        seed: u64,
        trainable: bool,
    ) -> Result<RigidFormer, ModelError> {
        if unit.enabled(&self.config.dynamics) {
            return Err(ModelError::InvalidInput(format!(
                "the model already has the {}",
                unit.name()
            )));
        }
        let mut config = self.config.clone();
        unit.set(&mut config.dynamics, true);
        self.with_new_parts(config, seed, trainable)
    }

    /// A model of `config`, a configuration that adds parts to this one's: every weight of this
    /// model copied, every parameter it lacks taken from a new model of `config` drawn from
    /// `seed` (parts whose last layer starts at zero then leave the function unchanged).
    fn with_new_parts(
        &self,
        config: crate::ModelConfig,
        seed: u64,
        trainable: bool,
    ) -> Result<RigidFormer, ModelError> {
        let fresh = RigidFormer::new_frozen(config.clone(), seed, &self.device)?.weight_copies()?;
        let mut tensors = self.weight_copies()?;
        for (name, t) in fresh {
            tensors.entry(name).or_insert(t);
        }
        self.rebuilt(config, tensors, trainable)
    }

    /// Copies of every weight, by name: the new model's weights never share storage with this
    /// one's.
    fn weight_copies(&self) -> Result<HashMap<String, Tensor>, ModelError> {
        let vars = self
            .varmap
            .data()
            .lock()
            .map_err(|_| ModelError::Internal("parameter map lock poisoned".into()))?;
        let mut tensors = HashMap::new();
        for (name, var) in vars.iter() {
            tensors.insert(name.clone(), var.as_tensor().detach().copy()?);
        }
        Ok(tensors)
    }

    /// A model of `config` from `tensors`, with this one's name and execution settings.
    fn rebuilt(
        &self,
        config: crate::ModelConfig,
        tensors: HashMap<String, Tensor>,
        trainable: bool,
    ) -> Result<RigidFormer, ModelError> {
        let store = ParamStore::loaded(tensors, &self.device, trainable);
        Ok(
            RigidFormer::from_store(self.name.clone(), config, store, &self.device)?
                .with_max_pass_objects(self.max_pass_objects)
                .with_fused_kernels(self.fused_kernels)
                .with_scene_threads(self.scene_threads),
        )
    }
}

/// Parameters of a decoder block (after `decoder.blocks.{l}.`) that a block inserted by
/// [`RigidFormer::deepened`] starts at zero: the attention's output projection, the FiLM's
/// last layer and the feed-forward's output, so the block adds nothing and modulates nothing.
const IDENTITY_AT_START: [&str; 4] = [
    "attn.out.weight",
    "film.1.weight",
    "film.1.bias",
    "ffn.down.weight",
];

impl RigidFormer {
    /// A deeper copy of this model: one new decoder block right after each block index in
    /// `insert_after` (0-based, distinct, each below [`crate::ModelConfig::blocks`]). The new
    /// blocks are drawn from `seed` with their attention output, FiLM output and feed-forward
    /// output layers zero, so each passes its input through unchanged and the copy's outputs
    /// equal this model's; an anchor tap on a block that gets a new one after it moves to the
    /// new block, so the anchors read the added depth. Every other weight is copied.
    /// `trainable` keeps gradient tracking on the copy's weights.
    pub fn deepened(
        &self,
        insert_after: &[usize],
        seed: u64,
        trainable: bool,
    ) -> Result<RigidFormer, ModelError> {
        let old = self.config.blocks;
        let mut after = insert_after.to_vec();
        after.sort_unstable();
        after.dedup();
        if after.is_empty() || after.len() != insert_after.len() || after[after.len() - 1] >= old {
            return Err(ModelError::InvalidInput(format!(
                "blocks to insert after must be distinct indices below {old}, got {insert_after:?}"
            )));
        }
        // New index of every old block, and the indices of the inserted ones.
        let (mut moved, mut inserted) = (Vec::with_capacity(old), Vec::new());
        for l in 0..old {
            moved.push(l + inserted.len());
            if after.contains(&l) {
                inserted.push(l + inserted.len() + 1);
            }
        }
        let mut config = self.config.clone();
        config.blocks = old + inserted.len();
        config.anchor_taps = config
            .anchor_taps
            .iter()
            .map(|&t| moved[t] + usize::from(after.contains(&t)))
            .collect();
        config.validate()?;
        let fresh = RigidFormer::new_frozen(config.clone(), seed, &self.device)?.weight_copies()?;
        let block_of = |name: &str| -> Option<(usize, String)> {
            let rest = name.strip_prefix("decoder.blocks.")?;
            let (l, tail) = rest.split_once('.')?;
            Some((l.parse().ok()?, tail.to_string()))
        };
        let mut tensors = HashMap::new();
        for (name, t) in self.weight_copies()? {
            match block_of(&name) {
                Some((l, tail)) => tensors.insert(format!("decoder.blocks.{}.{tail}", moved[l]), t),
                None => tensors.insert(name, t),
            };
        }
        for (name, t) in fresh {
            if let Some((l, tail)) = block_of(&name)
                && inserted.contains(&l)
            {
                let t = if IDENTITY_AT_START.contains(&tail.as_str()) {
                    t.zeros_like()?
                } else {
                    t
                };
                tensors.insert(name, t);
            }
        }
        self.rebuilt(config, tensors, trainable)
    }
}

/// Parameters whose layout depends on the encoder's widths, as `(name, zero_new_rows,
/// zero_new_columns)` for [`RigidFormer::widened_encoder`]: the last layer of each widened
/// MLP starts with zero rows for its new output channels and zero columns for its new hidden
/// units, so the new channels are exactly zero and the old ones unchanged; every new input
/// column of a consumer (it multiplies a zero channel) and every new hidden unit's input row
/// keep their fresh random values, so gradients reach the new weights from the first step.
const ENCODER_WIDTH_PARAMETERS: [(&str, bool, bool); 10] = [
    ("encoder.point.0.weight", false, false),
    ("encoder.point.0.bias", false, false),
    ("encoder.point.1.weight", true, true),
    ("encoder.point.1.bias", true, false),
    ("encoder.sa1.0.weight", false, false),
    ("encoder.sa1.0.bias", false, false),
    ("encoder.sa1.1.weight", true, true),
    ("encoder.sa1.1.bias", true, false),
    ("encoder.sa2.0.weight", false, false),
    (QUERY_IN_WEIGHT, false, false),
];

/// The anchor queries' input layer, `[width, point_dim + 3 + point_dim + rope_dim]`: its
/// columns are the anchor's own point feature, its offset, its pooled point feature and its
/// rotary features, in that order.
const QUERY_IN_WEIGHT: &str = "anchors.query_in.weight";

impl RigidFormer {
    /// A copy of this model with a wider point encoder: `point_dim` channels in the per-point
    /// MLP (hidden and output; the anchors read them too) and `sa_dim` in the first
    /// set-abstraction level, each at least the current width. Old weights are copied into
    /// their places, new ones are drawn from `seed` with the widened MLPs' new output rows and
    /// new hidden columns zero, so the copy's outputs equal this model's. `trainable` keeps
    /// gradient tracking on the copy's weights.
    ///
    /// Errors if a width is smaller than the current one or both are unchanged.
    pub fn widened_encoder(
        &self,
        point_dim: usize,
        sa_dim: usize,
        seed: u64,
        trainable: bool,
    ) -> Result<RigidFormer, ModelError> {
        let (c1, c2) = (self.config.point_dim, self.config.sa_dim);
        if point_dim < c1 || sa_dim < c2 || (point_dim, sa_dim) == (c1, c2) {
            return Err(ModelError::InvalidInput(format!(
                "encoder widths must grow from ({c1}, {c2}) without shrinking, got ({point_dim}, {sa_dim})"
            )));
        }
        let mut config = self.config.clone();
        (config.point_dim, config.sa_dim) = (point_dim, sa_dim);
        config.validate()?;
        let fresh = RigidFormer::new_frozen(config.clone(), seed, &self.device)?.weight_copies()?;
        let mut tensors = self.weight_copies()?;
        // Where each old query_in column goes: the same place in its segment of the new layout.
        let (old_segments, new_segments) = (query_segments(&self.config), query_segments(&config));
        let query_column = |j: usize| {
            let (mut old_start, mut new_start) = (0, 0);
            for (old_width, new_width) in old_segments.iter().zip(&new_segments) {
                if j < old_start + old_width {
                    return new_start + (j - old_start);
                }
                (old_start, new_start) = (old_start + old_width, new_start + new_width);
            }
            new_start + (j - old_start)
        };
        for (name, zero_rows, zero_columns) in ENCODER_WIDTH_PARAMETERS {
            let missing = |what: &str| {
                ModelError::Internal(format!("the {what} model has no parameter {name}"))
            };
            let old = tensors.remove(name).ok_or_else(|| missing("widened"))?;
            let new = fresh.get(name).ok_or_else(|| missing("fresh"))?;
            let column: &dyn Fn(usize) -> usize = if name == QUERY_IN_WEIGHT {
                &query_column
            } else {
                &|j| j
            };
            tensors.insert(
                name.to_string(),
                embed(&old, new, column, zero_rows, zero_columns)?,
            );
        }
        self.rebuilt(config, tensors, trainable)
    }
}

/// `new` (a vector `[r']` or a matrix `[r', c']`) with `old` (`[r]` or `[r, c]`, r <= r',
/// c <= c') written into rows `0..r` and columns `column(0..c)`; with `zero_rows` rows from
/// `r` on are zero, with `zero_columns` the columns no old one maps to are zero.
fn embed(
    old: &Tensor,
    new: &Tensor,
    column: &dyn Fn(usize) -> usize,
    zero_rows: bool,
    zero_columns: bool,
) -> Result<Tensor, ModelError> {
    let as_matrix = |t: &Tensor| -> Result<(usize, usize, Vec<f32>), ModelError> {
        let dims = t.dims();
        let (r, c) = match dims {
            [r] => (*r, 1),
            [r, c] => (*r, *c),
            _ => {
                return Err(ModelError::Internal(format!(
                    "cannot widen a parameter of shape {dims:?}"
                )));
            }
        };
        Ok((r, c, t.flatten_all()?.to_vec1::<f32>()?))
    };
    let (r, c, from) = as_matrix(old)?;
    let (r2, c2, mut to) = as_matrix(new)?;
    if r > r2 || c > c2 || (c > 0 && column(c - 1) >= c2) {
        return Err(ModelError::Internal(format!(
            "cannot embed a [{r}, {c}] parameter in a [{r2}, {c2}] one"
        )));
    }
    let mut mapped = vec![false; c2];
    for j in 0..c {
        mapped[column(j)] = true;
    }
    for i in 0..r2 {
        for (j2, &is_old) in mapped.iter().enumerate() {
            if (zero_rows && i >= r) || (zero_columns && !is_old) {
                to[i * c2 + j2] = 0.0;
            }
        }
        if i < r {
            for j in 0..c {
                to[i * c2 + column(j)] = from[i * c + j];
            }
        }
    }
    Ok(Tensor::from_vec(to, new.dims(), new.device())?.to_dtype(new.dtype())?)
}
