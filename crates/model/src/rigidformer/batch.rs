//! What one batched forward pass reads: the scenes' requests ([`SceneRequest`]) and the flat
//! host buffers built from them ([`BatchInputs`], assembled by [`super::inputs`]).

use candle_core::Tensor;

use crate::api::Pose;
use crate::kernels::avp::padded_distances;
use crate::prepare::PreparedScene;

/// One scene's request as the network sees it (poses already validated and normalised).
pub(crate) struct SceneRequest<'a> {
    pub scene: &'a PreparedScene,
    pub previous: Vec<Pose>,
    pub current: Vec<Pose>,
    /// Poses one step before `previous`, when known (read by history inputs only).
    pub earlier: Option<Vec<Pose>>,
    pub dt_steps: u32,
}

/// The network inputs that depend on the objects' poses, as tensors of an autograd graph
/// (gradient passes, [`super::pose_inputs`]): when present they replace the host buffers of
/// the same names, whose values they carry.
pub(crate) struct PoseInputs {
    /// `[P, F]`, as [`BatchInputs::feats`].
    pub feats: Tensor,
    /// `[O * S * G, 3]`, as [`BatchInputs::group_rel`].
    pub group_rel: Tensor,
    /// `[O * S, 3]`, as [`BatchInputs::centre_rel`].
    pub centre_rel: Tensor,
    /// `[O, K, 3]`, as [`BatchInputs::anchor_rel`].
    pub anchor_rel: Tensor,
    /// `[O, K, 2P]`, as [`BatchInputs::anchor_rope`].
    pub anchor_rope: Tensor,
    /// `[O * K, P]`, as [`BatchInputs::anchor_cos`].
    pub anchor_cos: Tensor,
    /// `[O * K, P]`, as [`BatchInputs::anchor_sin`].
    pub anchor_sin: Tensor,
    /// `[O, P]`, as [`BatchInputs::object_cos`].
    pub object_cos: Tensor,
    /// `[O, P]`, as [`BatchInputs::object_sin`].
    pub object_sin: Tensor,
    /// `[O, OBJECT_SUMMARY_FEATURES]`, as [`BatchInputs::object_summary`]; `None` when the
    /// model has none.
    pub object_summary: Option<Tensor>,
}

/// Everything one batched forward pass needs, as flat host buffers.
pub(crate) struct BatchInputs<'a> {
    /// Scenes.
    pub b: usize,
    /// Largest object count in the batch.
    pub mmax: usize,
    /// Largest point count per object in the batch.
    pub nmax: usize,
    /// Total objects.
    pub o: usize,
    /// First object row of each scene, `[b + 1]`.
    pub scene_offsets: Vec<usize>,
    /// Total points of the batch (`P`).
    pub points: usize,
    /// Normalised features of every point, packed without padding `[P, F]` (F from the
    /// configuration, objects in
    /// order, each object's points contiguous).
    pub feats: Vec<f32>,
    /// Packed point row of every padded slot `[o, nmax]`; `P` (a zero row) for padding.
    pub pad_idx: Vec<u32>,
    /// First packed point row and point count of every object, `[o]`.
    pub object_points: Vec<(usize, usize)>,
    /// Neighbour rows into the packed points, `[o, S, G]`.
    pub group_idx: Vec<u32>,
    /// Neighbour minus centre, world frame, scaled, `[o, S, G, 3]`.
    pub group_rel: Vec<f32>,
    /// Centre minus object centroid, world frame, scaled, `[o, S, 3]`.
    pub centre_rel: Vec<f32>,
    /// Squared anchor-to-point distances of every object, `[K, n]` each (its point count `n`),
    /// m^2, borrowed from the prepared scenes (they do not change between steps).
    pub anchor_d2: Vec<&'a [f32]>,
    /// 1 for a real point, 0 for padding, `[o, 1, nmax]`.
    pub point_mask: Vec<f32>,
    /// Anchor rows into the packed points, `[o, K]`.
    pub anchor_idx: Vec<u32>,
    /// Anchor minus object centroid, world frame, scaled, `[o, K, 3]`.
    pub anchor_rel: Vec<f32>,
    /// Per-anchor rotary features `[o, K, 2P]`: P cosines then P sines.
    pub anchor_rope: Vec<f32>,
    /// Per-anchor cosines `[o, K, P]` and sines (for rotating anchor queries).
    pub anchor_cos: Vec<f32>,
    /// See `anchor_cos`.
    pub anchor_sin: Vec<f32>,
    /// Object ARoPE descriptors (mean over anchors), `[o, P]` cosines and sines.
    pub object_cos: Vec<f32>,
    /// See `object_cos`.
    pub object_sin: Vec<f32>,
    /// log2(dt_steps) per scene `[b]`.
    pub tau: Vec<f32>,
    /// Step size in frames per object `[o]`.
    pub object_dt: Vec<u32>,
    /// Object state summaries `[o, OBJECT_SUMMARY_FEATURES]`
    /// ([`object_summary`](super::features::object_summary)); empty when the model has none.
    pub object_summary: Vec<f32>,
    /// Contact summaries `[o, CONTACT_SUMMARY_FEATURES]`
    /// ([`contact_summary`](super::features::contact_summary)); empty when the model has none.
    pub contact_summary: Vec<f32>,
    /// Every packed point's lever matrix `[P, 9]` ([`super::wrench::wrench_geometry`]); empty
    /// without `dynamics.contact_wrench`.
    pub point_lever: Vec<f32>,
    /// Every anchor's spin matrix `[o, K, 9]` ([`super::wrench::wrench_geometry`]); empty
    /// without `dynamics.contact_wrench`.
    pub anchor_spin: Vec<f32>,
    /// Packed rows of the points whose contact search found another object's point
    /// ([`super::messages`]), `[Pc]`; empty without `dynamics.contact_messages`.
    pub contact_rows: Vec<u32>,
    /// The packed row of each of those points' partner (the other object's point found),
    /// `[Pc]`.
    pub partner_row: Vec<u32>,
    /// Both lever arms of each of those contacts, `[Pc, 6]`, world frame, scaled by 1 / the
    /// position scale: the point's offset from its object's centroid, then its partner's from
    /// the partner's centroid.
    pub partner_levers: Vec<f32>,
    /// The Verlet base of every anchor before free fall, per object `[K]`, world frame,
    /// metres (f64): where the anchor goes at constant velocity
    /// ([`super::base_prediction::verlet_base`]).
    pub anchors_base: Vec<Vec<[f64; 3]>>,
    /// Anchors in the reference (body) frame, per object `[K]`, metres (f64).
    pub anchors_ref: Vec<Vec<[f64; 3]>>,
    /// How far the Verlet base raises each object so no point is below the floor, `[o]`
    /// metres (>= 0; empty without `dynamics.floor_base`).
    pub floor_lift: Vec<f64>,
    /// Objects certainly in free flight over the step, `[o]`, which move on the Verlet base
    /// alone ([`super::free_flight`]); empty without `dynamics.free_flight_gate`.
    pub free_flight: Vec<bool>,
    /// The reference cloud (body frame, metres) of every object the floor projection
    /// ([`ModelConfig::floor_projection`](crate::ModelConfig::floor_projection)) may raise,
    /// `[o]`: `None` for a kinematic object; empty without the projection or a floor.
    pub floor_clouds: Vec<Option<&'a [[f32; 3]]>>,
    /// Current rotation per object (for the quaternion sign of the output).
    pub current_rot: Vec<[f32; 4]>,
    /// Smallest distance from a point of each object to another object's point at t, found
    /// by the contact search, `[o]` metres; infinite when none is within the contact radius.
    pub object_gap: Vec<f32>,
    /// The pose-dependent inputs as graph tensors (gradient passes only; `None` otherwise).
    pub pose_inputs: Option<PoseInputs>,
}

impl BatchInputs<'_> {
    /// The AVP distances laid out `[o, K, nmax]` with zero padding (the composition's layout).
    pub fn avp_d2_padded(&self, k: usize) -> Vec<f32> {
        padded_distances(&self.anchor_d2, k, self.nmax)
    }
}
