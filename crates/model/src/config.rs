//! Model configuration: architecture sizes and the data conventions a checkpoint was trained
//! with. Stored as `config.json` in every checkpoint directory.

use serde::{Deserialize, Serialize};

use crate::ModelError;
use crate::trained_ranges::TrainedRanges;

/// Architecture name stored in a RigidFormer `config.json`; also the name a newly built or
/// trained model carries (a loaded checkpoint is named by its directory).
pub const RIGIDFORMER: &str = "rigidformer";

/// Current `config.json` format version.
pub const FORMAT_VERSION: u32 = 1;

/// Number of per-point input features every model has: contact displacement (3), per-step
/// increment (3), offset from the reference cloud (3), physical parameters (3).
pub const BASE_POINT_FEATURES: usize = 12;

/// Features appended after the base ones when [`DynamicsConfig::contact_velocity`] is on: the
/// contact surface's increment relative to the point's own (3).
pub const CONTACT_VELOCITY_FEATURES: usize = 3;

/// Features appended after the base ones and the contact velocity (if on) when
/// [`DynamicsConfig::surface_normals`] is on: the point's own outward normal (3), the normal of
/// the surface its contact feature reaches (3) and its height above that surface's tangent
/// plane (1).
pub const SURFACE_NORMAL_FEATURES: usize = 7;

/// Features appended after the base ones, the contact velocity and the surface normals (each
/// if on) when [`DynamicsConfig::history`] is on: the point's acceleration over the previous
/// two steps beyond free fall (3).
pub const HISTORY_FEATURES: usize = 3;

/// Features appended after every other optional group (each if on) when
/// [`DynamicsConfig::approach`] is on: the speed at which the point closes on the surface its
/// contact feature reaches (1), the fraction of the step before it would reach it (1) and how
/// far behind it a free step would carry it (1).
pub const APPROACH_FEATURES: usize = 3;

/// Features appended after every other optional group (each if on) when
/// [`DynamicsConfig::contact_partner`] is on: whether the surface the point's contact feature
/// reaches belongs to another object (1) or not (0: the floor, or nothing within the contact
/// radius), and that object's `ln` mass less the point's own object's (clamped to
/// [`CONTACT_PARTNER_MAX_LN_RATIO`]), friction and restitution (3; zero when it is not an
/// object).
pub const CONTACT_PARTNER_FEATURES: usize = 4;

/// Largest magnitude of the `ln` mass ratio among the contact partner features (a factor of
/// about 150 either way).
pub const CONTACT_PARTNER_MAX_LN_RATIO: f32 = 5.0;

/// Numbers per object in the object state summary ([`DynamicsConfig::object_summary`]).
pub const OBJECT_SUMMARY_FEATURES: usize = 14;

/// Numbers per object in the contact summary ([`DynamicsConfig::contact_summary`]).
pub const CONTACT_SUMMARY_FEATURES: usize = 11;

/// Affine normalisation of the per-point input features: `(raw - mean) / std`, one value per
/// feature ([`DynamicsConfig::point_features`]: 12, plus 3 with the contact velocity, plus 7
/// with the surface normals, plus 3 with the history, plus 3 with the approach).
///
/// Layout: `[contact_x, contact_y, contact_z, v_x, v_y, v_z, r_x, r_y, r_z, ln(mass / 1 kg),
/// friction, restitution]`, then `[cv_x, cv_y, cv_z]` with the contact velocity, then `[n_x,
/// n_y, n_z, m_x, m_y, m_z, gap]` with the surface normals (unit vectors; the gap in metres), then
/// `[a_x, a_y, a_z]` with the history (metres per frame^2 with per-frame units), then
/// `[closing, reach, depth]` with the approach (metres per frame, a fraction of the step,
/// metres per frame with per-frame units). Contact
/// displacement, increment, offset and contact velocity are in metres (increments per step of
/// `dt_steps` frames, or per frame with per-frame units); mass enters as its natural logarithm.
/// The trainer fits these from data; the defaults are sensible for MOVi-like scenes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FeatureNormalization {
    /// Per-feature mean subtracted first, `[features]`.
    pub mean: Vec<f32>,
    /// Per-feature scale divided by afterwards (must be finite and > 0), `[features]`.
    pub std: Vec<f32>,
}

impl Default for FeatureNormalization {
    /// The 12 base features' defaults.
    fn default() -> Self {
        FeatureNormalization {
            mean: vec![
                0.0, 0.0, -0.1, // contact (the ground pulls the mean down)
                0.0, 0.0, 0.0, // per-step increment
                0.0, 0.0, 1.0, // offset from the reference cloud ~ world position
                0.5, 0.6, 0.5, // ln mass, friction, restitution
            ],
            std: vec![
                0.1, 0.1, 0.1, //
                0.05, 0.05, 0.05, //
                2.5, 2.5, 1.0, //
                1.0, 0.2, 0.2,
            ],
        }
    }
}

impl FeatureNormalization {
    /// Default constants for the features `dynamics` selects (the contact velocity, if on,
    /// gets mean 0 and the increment's scale; the surface normals mean 0 and scale 0.5, their
    /// gap the contact feature's; the approach's speeds the increment's scale; the contact
    /// partner's flag and materials centred near zero, since most points touch no object).
    pub fn defaults_for(dynamics: &DynamicsConfig) -> FeatureNormalization {
        let mut n = FeatureNormalization::default();
        if dynamics.contact_velocity {
            n.mean.extend([0.0; CONTACT_VELOCITY_FEATURES]);
            n.std.extend([0.05; CONTACT_VELOCITY_FEATURES]);
        }
        if dynamics.surface_normals {
            n.mean.extend([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.1]);
            n.std.extend([0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.1]);
        }
        if dynamics.history {
            n.mean.extend([0.0; HISTORY_FEATURES]);
            n.std.extend([0.01; HISTORY_FEATURES]);
        }
        if dynamics.approach {
            n.mean.extend([0.0, 1.0, 0.0]);
            n.std.extend([0.05, 0.3, 0.05]);
        }
        if dynamics.contact_partner {
            // Most points touch no other object: the flag and the rest are mostly zero.
            n.mean.extend([0.1, 0.0, 0.05, 0.05]);
            n.std.extend([0.3, 0.5, 0.2, 0.2]);
        }
        n
    }

    /// Number of features these constants normalise.
    pub fn len(&self) -> usize {
        self.mean.len()
    }

    /// True when there are no constants at all (never valid).
    pub fn is_empty(&self) -> bool {
        self.mean.is_empty()
    }
}

/// Weights of the one-step training loss (equal weights by default; see `docs/rigidformer.md`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LossConfig {
    /// Smooth L1 transition point, in units of `scale` (dimensionless).
    pub beta: f32,
    /// Differences (metres, or metres per step^2) are divided by this before the Smooth L1, so
    /// the loss sees O(1) numbers. Metres.
    pub scale: f32,
    /// Weights of `[pos_pre, acc_pre, pos_post, acc_post]`.
    pub weights: [f32; 4],
    /// Factor on the errors of objects at rest in the training window (ground truth: the
    /// previous, current and target poses within [`REST_TRANSLATION_PER_FRAME_M`] and
    /// [`REST_ROTATION_PER_FRAME_RAD`] per frame of each other); 1 weighs them as any
    /// object. Dimensionless, > 0; absent in older `config.json` files, which means 1.
    #[serde(default = "unit_weight")]
    pub rest_weight: f32,
    /// Factor on the errors of moving objects that touch another object at the window's
    /// current frame t: some point of theirs within [`OBJECT_CONTACT_WEIGHT_DISTANCE_M`] of
    /// another object's point (the contact search the inputs run anyway). Resting objects keep
    /// `rest_weight`. 1 weighs them as any object. Dimensionless, > 0; absent in older
    /// `config.json` files, which means 1.
    #[serde(default = "unit_weight")]
    pub object_contact_weight: f32,
    /// Weight of a fifth loss term on each object's rotation error: the post-projection
    /// anchor errors less their mean over the object's anchors (what is left is the rotation
    /// error times each anchor's lever arm), rescaled to a lever arm of
    /// [`ROTATION_LEVER_ARM_M`] by the object's anchor radius, so an error of so many degrees
    /// weighs the same on a small object as on a large one (the anchor terms weigh it by the
    /// object's size; the evaluation scores degrees). Same units, step-size balance and object
    /// weights as the anchor terms. Dimensionless, >= 0; 0, or absent in older `config.json`
    /// files, leaves the method's four terms alone.
    #[serde(default)]
    pub rotation_weight: f32,
}

/// Lever arm at which [`LossConfig::rotation_weight`]'s term measures rotation errors, metres,
/// about the anchor radius of a MOVi-sized object (unit shapes at scale 0.7-1.4): one loss unit
/// (1 mm) there is 2 milliradians (0.11 degrees).
pub const ROTATION_LEVER_ARM_M: f32 = 0.5;

/// Smallest anchor radius [`LossConfig::rotation_weight`]'s term divides by, metres.
pub const ROTATION_MIN_RADIUS_M: f32 = 0.01;

/// Contact test of [`LossConfig::object_contact_weight`]: largest distance from one of an
/// object's points to another object's point, metres.
pub const OBJECT_CONTACT_WEIGHT_DISTANCE_M: f32 = 0.1;

/// Resting test of [`LossConfig::rest_weight`]: largest centre displacement per frame, metres
/// (0.5 mm a frame: 1.2 cm/s at 24 frames a second).
pub const REST_TRANSLATION_PER_FRAME_M: f32 = 5.0e-4;
/// Resting test of [`LossConfig::rest_weight`]: largest rotation per frame, radians (0.05
/// degrees a frame: 1.2 degrees a second at 24 frames a second).
pub const REST_ROTATION_PER_FRAME_RAD: f32 = 8.7e-4;

fn unit_weight() -> f32 {
    1.0
}

impl Default for LossConfig {
    fn default() -> Self {
        // Quadratic only below 1 mm: every larger error pulls with the same force, so the
        // millimetre precision that keeps resting objects still is not drowned by the large,
        // barely predictable errors of impacts (with 1 cm, a resting object's 1.5 mm one-step
        // error weighed a hundredth of an impact's).
        LossConfig {
            beta: 1.0,
            scale: 0.001,
            weights: [1.0; 4],
            rest_weight: 1.0,
            object_contact_weight: 1.0,
            rotation_weight: 0.0,
        }
    }
}

/// How the network's inputs and outputs relate to the physics (see `docs/rigidformer.md`).
///
/// Every switch off is the original parametrisation, which is what a `config.json` without a
/// `dynamics` section means; the presets switch every one on.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DynamicsConfig {
    /// Predict the residual on top of free fall: the Verlet base becomes
    /// `2 A_t - A_{t-1} + g (k dt_frame)^2`, so an object in flight needs a zero output.
    pub gravity_residual: bool,
    /// Express velocities and accelerations per frame instead of per step of `k` frames: the
    /// per-point increment feature is divided by `k`, the head's output is multiplied by `k^2`
    /// and the loss divides step-`k` errors by `k^2`, so every step size sees O(1) numbers and
    /// carries the same weight.
    pub per_frame_units: bool,
    /// Inputs that do not see absolute horizontal position (the floor is infinite): the
    /// offset feature is taken from the object's own centre in x and y (z stays absolute, the
    /// floor is at `ground_z`), and the anchor queries' positional features are relative to the
    /// object's centroid. Attention rotaries stay world-frame (only differences enter there).
    pub translation_invariant: bool,
    /// Contact velocity feature: per point, the increment of the contact surface it reaches
    /// relative to its own increment (zero when nothing is within the contact radius, minus
    /// its own increment for the ground), in the increment feature's units. Adds
    /// [`CONTACT_VELOCITY_FEATURES`] inputs after the base ones.
    pub contact_velocity: bool,
    /// Surface normal features: per point, its outward normal estimated from the reference
    /// cloud (a plane fitted to its nearest points, signed away from the centroid; world
    /// frame), the normal of the surface its contact feature reaches (the nearest other
    /// point's, `+z` for the ground, zero when nothing is within the contact radius) and its
    /// height above that surface's tangent plane in metres (negative when it is behind it;
    /// the contact radius when nothing is near). Between two sparsely sampled faces the
    /// point-to-point distance is off by up to half the spacing of the points; the
    /// point-to-plane height is not. Adds [`SURFACE_NORMAL_FEATURES`] inputs after the base
    /// ones and the contact velocity. Absent in older `config.json` files, which means off.
    pub surface_normals: bool,
    /// History inputs: per point, how its motion changed over the previous step, from the
    /// poses one step before the previous ones ([`crate::SceneState::earlier`]): `(x_t - 2
    /// x_{t-k} + x_{t-2k} - g (k dt_frame)^2) / d^2` with `d` the increment divisor (metres per
    /// frame^2 with per-frame units; zero in free flight), zero when those poses are not
    /// known. At a contact two poses cannot tell how a body moves at t (its velocity changed
    /// within the last step); the third tells how it changed. Adds [`HISTORY_FEATURES`]
    /// inputs after the surface normals. Absent in older `config.json` files, which means off.
    pub history: bool,
    /// Approach inputs: per point, from its contact feature's surface (the nearest other
    /// point's tangent plane, or the ground) and the contact velocity, the speed at which it
    /// closes on that surface along its normal (metres per step, divided by the increment
    /// divisor), the fraction of the step before a free step would reach the surface (0 when
    /// it is there, 1 when it does not reach it within the step) and how far behind the surface
    /// the free step would end (metres, divided by the increment divisor; 0 when it does not
    /// reach it). The network could form these from the contact velocity, the normal and the
    /// height, but only as products and a quotient; at a fast impact they say when within the
    /// step the surfaces meet and how much motion the contact has to take away. Adds
    /// [`APPROACH_FEATURES`] inputs after the history. Absent in older `config.json` files,
    /// which means off.
    pub approach: bool,
    /// Every point also reads the parameters of the object its contact feature reaches
    /// ([`CONTACT_PARTNER_FEATURES`]: a flag, the `ln` mass ratio to its own object, friction
    /// and restitution). The other features give the touched surface's position, velocity and
    /// normal but not its object's mass, which decides how a collision shares momentum and
    /// otherwise reaches the point only through attention between whole objects. Adds
    /// [`CONTACT_PARTNER_FEATURES`] inputs after the approach. Absent in older `config.json`
    /// files, which means off.
    pub contact_partner: bool,
    /// Extrapolate each object as a rigid body in the Verlet base: the base keeps the object's
    /// linear and angular velocity (`R_{t+k} = R_t R_{t-k}^T R_t`, centre `2 p_t - p_{t-k}`)
    /// instead of extrapolating every anchor linearly (`2 A_t - A_{t-k}`), which lags a
    /// spinning body's rotation by about `5/6 theta^3` radians for `theta` radians per step
    /// (18 degrees at 0.83 rad per step). A body spinning in free flight then needs a zero
    /// output, as one flying straight does with `gravity_residual`.
    pub rigid_extrapolation: bool,
    /// Object state summary: [`OBJECT_SUMMARY_FEATURES`] numbers per object (the lowest
    /// point's height above the ground and increment, the centre's height and increment, the
    /// rotation increment, the lowest point's offset from the centre), added to the object's
    /// token through a small MLP whose last layer starts at zero, so the floor reaches the
    /// decoder without passing through the encoder's max-pools. Absent in older `config.json`
    /// files, which means off.
    pub object_summary: bool,
    /// Contact summary: [`CONTACT_SUMMARY_FEATURES`] numbers per object describing where it
    /// meets other objects (the nearest gap, and over the patch of its points nearly that
    /// close: the mean direction to the other surface, the mean offset from the centre and the
    /// mean contact velocity; the patch's share of the cloud), added to the object's token
    /// through a second MLP whose last layer starts at zero. It is the object summary's lever
    /// arm for contacts between objects, which the floor's summary does not see. Absent in
    /// older `config.json` files, which means off.
    pub contact_summary: bool,
    /// A Verlet base that respects the floor: after the constant-velocity extrapolation and
    /// free fall, the object is raised just enough that no point of its reference cloud is
    /// below `ground_z` (the ballistic-with-floor baseline's inelastic floor). A body at rest on
    /// the floor or landing then needs a small output (the rebound) instead of cancelling a
    /// free fall or a penetration of up to a step's travel. Absent in older `config.json`
    /// files, which means off.
    pub floor_base: bool,
    /// Scene-relative mass: before the features are computed, every mass of a scene is
    /// multiplied by one factor chosen so that the mean `ln(mass / kg)` of its dynamic
    /// (not kinematic) objects equals the normalisation mean of the mass feature
    /// ([`LN_MASS_FEATURE`]). Rigid bodies under gravity and contact move the same under such a
    /// common factor, and the model then answers the same too: only mass ratios reach it. A
    /// kinematic body's mass moves nothing: it sets no scale and is seen as that mean. Absent
    /// in older `config.json` files, which means off.
    pub relative_mass: bool,
    /// Free flight without the network: an object that can touch neither the floor nor any
    /// other object during the step (its bounding sphere's path, and every other object's,
    /// kept apart by more than either could be deflected within the step; see
    /// `docs/rigidformer.md`) moves exactly on the Verlet base, the rigid body's ballistic
    /// motion, whatever the network outputs. Only in scenes without kinematic objects (a
    /// kinematic body's next pose is not known to the model). Inference only; absent in
    /// older `config.json` files, which means off.
    pub free_flight_gate: bool,
    /// Kinematic lead: where a kinematic object's pose after the step is known (a session
    /// `Step` with actions, a driven evaluation), its previous and earlier poses are replaced
    /// before the step by those of constant motion into that pose
    /// ([`crate::SceneState::lead_kinematic`]), so every feature that reads its motion (its own
    /// increment, the contact velocity of the points it touches) reads the motion it is about
    /// to make rather than the one it just made. A pusher whose velocity changes every step is
    /// otherwise seen a step late. Applied by the callers, not by the step itself; absent in
    /// older `config.json` files, which means off.
    pub kinematic_lead: bool,
    /// Contact wrench: every point also predicts a force (a small MLP on its point feature and
    /// its object's token, last layer starting at zero); the forces' mean over the object's
    /// cloud is added to every anchor's acceleration, and their mean moment about the cloud's
    /// centroid, divided by the cloud's inertia, gives an angular acceleration `alpha` that adds
    /// `alpha x r_k` to anchor `k` (`r_k` its offset from the centroid). The torque a contact
    /// imparts is then the sum over the points it touches of lever arm times force, formed by
    /// the unit rather than learnt by the per-anchor head. Absent in older `config.json` files,
    /// which means off.
    pub contact_wrench: bool,
    /// Contact messages: every point whose contact search found another object's point gets a
    /// message from that point, an MLP on both points' encoder features and on both lever arms
    /// (each point's offset from its own object's centroid), added to its feature before the
    /// set abstraction (last layer starting at zero). Objects otherwise meet only as whole
    /// tokens in attention; a contact's exchange depends on where on each body it lies. Absent
    /// in older `config.json` files, which means off.
    pub contact_messages: bool,
}

/// An optional network unit a trained model can gain (its last layer starting at zero, so
/// the model keeps its function): the one place that knows each unit's switch and name.
/// Adding one to a trained model is [`crate::RigidFormer::widened_with_unit`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModelUnit {
    /// [`DynamicsConfig::object_summary`]: an MLP from the object state summary to its token;
    /// parameters `summary.*`.
    ObjectSummary,
    /// [`DynamicsConfig::contact_summary`]: an MLP from the contact summary to its token;
    /// parameters `contact_summary.*`.
    ContactSummary,
    /// [`DynamicsConfig::contact_wrench`]; parameters `anchors.wrench.*`.
    ContactWrench,
    /// [`DynamicsConfig::contact_messages`]; parameters `messages.*`.
    ContactMessages,
}

impl ModelUnit {
    /// Every unit (the order in which a trainer adds them to a loaded model).
    pub const ALL: [ModelUnit; 4] = [
        ModelUnit::ObjectSummary,
        ModelUnit::ContactSummary,
        ModelUnit::ContactWrench,
        ModelUnit::ContactMessages,
    ];

    /// What the unit is called in messages.
    pub fn name(self) -> &'static str {
        match self {
            ModelUnit::ObjectSummary => "object state summary",
            ModelUnit::ContactSummary => "contact summary",
            ModelUnit::ContactWrench => "contact wrench",
            ModelUnit::ContactMessages => "contact messages",
        }
    }

    /// Its switch in [`DynamicsConfig`] and in a training configuration's `[model]`.
    pub fn key(self) -> &'static str {
        match self {
            ModelUnit::ObjectSummary => "object_summary",
            ModelUnit::ContactSummary => "contact_summary",
            ModelUnit::ContactWrench => "contact_wrench",
            ModelUnit::ContactMessages => "contact_messages",
        }
    }

    /// Whether `d` has it.
    pub fn enabled(self, d: &DynamicsConfig) -> bool {
        match self {
            ModelUnit::ObjectSummary => d.object_summary,
            ModelUnit::ContactSummary => d.contact_summary,
            ModelUnit::ContactWrench => d.contact_wrench,
            ModelUnit::ContactMessages => d.contact_messages,
        }
    }

    /// Switches it on or off in `d`.
    pub fn set(self, d: &mut DynamicsConfig, on: bool) {
        match self {
            ModelUnit::ObjectSummary => d.object_summary = on,
            ModelUnit::ContactSummary => d.contact_summary = on,
            ModelUnit::ContactWrench => d.contact_wrench = on,
            ModelUnit::ContactMessages => d.contact_messages = on,
        }
    }
}

/// An optional group of per-point inputs, in layout order after the base features: the
/// one place that knows each group's switch, size and position.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InputGroup {
    /// [`DynamicsConfig::contact_velocity`]: [`CONTACT_VELOCITY_FEATURES`] inputs.
    ContactVelocity,
    /// [`DynamicsConfig::surface_normals`]: [`SURFACE_NORMAL_FEATURES`] inputs.
    SurfaceNormals,
    /// [`DynamicsConfig::history`]: [`HISTORY_FEATURES`] inputs.
    History,
    /// [`DynamicsConfig::approach`]: [`APPROACH_FEATURES`] inputs.
    Approach,
    /// [`DynamicsConfig::contact_partner`]: [`CONTACT_PARTNER_FEATURES`] inputs.
    ContactPartner,
}

impl InputGroup {
    /// Every group, in layout order.
    pub const ALL: [InputGroup; 5] = [
        InputGroup::ContactVelocity,
        InputGroup::SurfaceNormals,
        InputGroup::History,
        InputGroup::Approach,
        InputGroup::ContactPartner,
    ];

    /// Name for messages, e.g. "contact velocity".
    pub fn name(self) -> &'static str {
        match self {
            InputGroup::ContactVelocity => "contact velocity",
            InputGroup::SurfaceNormals => "surface normals",
            InputGroup::History => "history",
            InputGroup::Approach => "approach",
            InputGroup::ContactPartner => "contact partner",
        }
    }

    /// Key of the group's switch in configurations, e.g. "contact_velocity" (the
    /// [`DynamicsConfig`] field and the training config's `[model]` option).
    pub fn key(self) -> &'static str {
        match self {
            InputGroup::ContactVelocity => "contact_velocity",
            InputGroup::SurfaceNormals => "surface_normals",
            InputGroup::History => "history",
            InputGroup::Approach => "approach",
            InputGroup::ContactPartner => "contact_partner",
        }
    }

    /// Number of per-point features the group adds.
    pub fn count(self) -> usize {
        match self {
            InputGroup::ContactVelocity => CONTACT_VELOCITY_FEATURES,
            InputGroup::SurfaceNormals => SURFACE_NORMAL_FEATURES,
            InputGroup::History => HISTORY_FEATURES,
            InputGroup::Approach => APPROACH_FEATURES,
            InputGroup::ContactPartner => CONTACT_PARTNER_FEATURES,
        }
    }

    /// Whether `dynamics` switches the group on.
    pub fn enabled(self, dynamics: &DynamicsConfig) -> bool {
        match self {
            InputGroup::ContactVelocity => dynamics.contact_velocity,
            InputGroup::SurfaceNormals => dynamics.surface_normals,
            InputGroup::History => dynamics.history,
            InputGroup::Approach => dynamics.approach,
            InputGroup::ContactPartner => dynamics.contact_partner,
        }
    }

    /// Switches the group on or off in `dynamics`.
    pub fn set(self, dynamics: &mut DynamicsConfig, on: bool) {
        match self {
            InputGroup::ContactVelocity => dynamics.contact_velocity = on,
            InputGroup::SurfaceNormals => dynamics.surface_normals = on,
            InputGroup::History => dynamics.history = on,
            InputGroup::Approach => dynamics.approach = on,
            InputGroup::ContactPartner => dynamics.contact_partner = on,
        }
    }

    /// Index of the group's first feature in the layout of `dynamics` (where it is or would
    /// be): after the base features and every enabled group before it.
    pub fn offset(self, dynamics: &DynamicsConfig) -> usize {
        BASE_POINT_FEATURES
            + InputGroup::ALL
                .iter()
                .take_while(|&&g| g != self)
                .filter(|g| g.enabled(dynamics))
                .map(|g| g.count())
                .sum::<usize>()
    }
}

/// Index of the `ln(mass / kg)` feature among the per-point features (see
/// [`FeatureNormalization`]).
pub const LN_MASS_FEATURE: usize = 9;

impl DynamicsConfig {
    /// Every improvement on (the presets).
    pub fn residual() -> DynamicsConfig {
        DynamicsConfig {
            gravity_residual: true,
            per_frame_units: true,
            translation_invariant: true,
            contact_velocity: true,
            surface_normals: false,
            history: false,
            approach: false,
            contact_partner: false,
            rigid_extrapolation: true,
            object_summary: false,
            contact_summary: false,
            floor_base: false,
            relative_mass: false,
            free_flight_gate: false,
            kinematic_lead: false,
            contact_wrench: false,
            contact_messages: false,
        }
    }

    /// Number of per-point input features: [`BASE_POINT_FEATURES`], plus
    /// [`CONTACT_VELOCITY_FEATURES`] with the contact velocity, plus
    /// [`SURFACE_NORMAL_FEATURES`] with the surface normals, plus [`HISTORY_FEATURES`] with the
    /// history, plus [`APPROACH_FEATURES`] with the approach, plus [`CONTACT_PARTNER_FEATURES`]
    /// with the contact partner.
    pub fn point_features(&self) -> usize {
        BASE_POINT_FEATURES
            + InputGroup::ALL
                .iter()
                .filter(|g| g.enabled(self))
                .map(|g| g.count())
                .sum::<usize>()
    }

    /// Whether the features need every point's surface normal (the surface normal or the
    /// approach inputs).
    pub fn reads_normals(&self) -> bool {
        self.surface_normals || self.approach
    }

    /// Divisor of the per-point increment feature at step size `k` frames.
    pub fn increment_divisor(&self, k: u32) -> f32 {
        if self.per_frame_units {
            k.max(1) as f32
        } else {
            1.0
        }
    }

    /// Factor from the head's (per frame^2) output to metres per step^2 at step size `k`.
    pub fn output_factor(&self, k: u32) -> f32 {
        if self.per_frame_units {
            (k.max(1) as f32).powi(2)
        } else {
            1.0
        }
    }
}

/// Architecture and data conventions of a RigidFormer checkpoint (`config.json`).
///
/// Every size is a value here; nothing about the network shape is hard-coded.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelConfig {
    /// Architecture name; `"rigidformer"`.
    pub architecture: String,
    /// `config.json` format version ([`FORMAT_VERSION`]).
    pub format_version: u32,

    // ---- data conventions ----
    /// Interval of one recorded frame in seconds (MOVi-like: 1/24).
    pub dt_frame: f32,
    /// Gravity of the training data, m/s^2 (z up).
    pub gravity: [f32; 3],
    /// Nominal number of surface points per object the model was trained with (a hint for
    /// clients; any count from 1 to `max_points_per_object` is accepted).
    pub points_per_object: usize,
    /// Largest accepted point count per object.
    pub max_points_per_object: usize,
    /// Largest accepted number of objects in one scene.
    pub max_objects: usize,
    /// Contact feature radius, metres (default 0.25).
    pub contact_radius: f32,
    /// Height of the ground plane's top in metres, or `None` for no ground.
    pub ground_z: Option<f32>,
    /// Normalisation of the per-point features ([`DynamicsConfig::point_features`]).
    pub normalization: FeatureNormalization,
    /// Scale dividing relative point positions inside the encoder, metres.
    pub position_scale: f32,

    // ---- encoder ----
    /// Width of the per-point features (shared point MLP output; pooled by AVP).
    pub point_dim: usize,
    /// Number of set-abstraction centres per object (farthest point sampling).
    pub sa_centres: usize,
    /// Neighbours grouped around each centre (nearest points on the reference cloud).
    pub sa_neighbours: usize,
    /// Width of the first set-abstraction level.
    pub sa_dim: usize,

    // ---- decoder ----
    /// Token width D.
    pub width: usize,
    /// Attention heads; `width` must be divisible by it.
    pub heads: usize,
    /// Decoder blocks L.
    pub blocks: usize,
    /// Learned register tokens R.
    pub registers: usize,
    /// SwiGLU hidden width.
    pub ffn_hidden: usize,
    /// Hidden width of the FiLM MLPs (one pair per block).
    pub film_hidden: usize,
    /// Width of each head's rotary part (ARoPE); a multiple of 6 (x, y, z pairs), at most the
    /// head width. The rest of the head passes through.
    pub rope_dim: usize,
    /// Lowest ARoPE frequency, radians per metre.
    pub rope_freq_min: f32,
    /// Highest ARoPE frequency, radians per metre.
    pub rope_freq_max: f32,
    /// RMSNorm epsilon.
    pub norm_eps: f32,

    // ---- anchors ----
    /// Anchors per object K.
    pub anchors: usize,
    /// Initial AVP bandwidth sigma, metres (learned as log sigma).
    pub avp_sigma: f32,
    /// Decoder depths (block indices, 0-based) whose outputs the anchor queries attend to.
    pub anchor_taps: Vec<usize>,
    /// Acceleration output scale, metres per step^2: the head predicts `a / accel_scale`.
    pub accel_scale: f32,
    /// A second, coarse output unit, metres per step^2 like `accel_scale`: the head predicts
    /// three more numbers per anchor in this unit and adds them to the fine ones, so a
    /// bounce's correction (tenths of a metre) and a resting body's (tenths of a millimetre)
    /// are each O(1) in one of the two. `None` (absent in older `config.json` files): one unit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub accel_coarse_scale: Option<f32>,

    /// Training loss settings.
    pub loss: LossConfig,
    /// Input and output parametrisation; absent in older checkpoints (all off).
    #[serde(default)]
    pub dynamics: DynamicsConfig,
    /// Floor projection, metres: after the Kabsch fit, an object with a point more than this
    /// depth below `ground_z` is raised along z until its lowest point is at that depth (its
    /// rotation and horizontal position kept): the floor's non-penetration constraint applied
    /// to the network's answer, as the Kabsch fit applies rigidity, with the small
    /// penetration a contact solver keeps at rest (its slop) left alone. Kinematic objects
    /// are never raised. Applied by the inference step, which pushforward training also
    /// runs; the loss reads the network's anchors before it. `None` (absent in older
    /// `config.json` files): off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub floor_projection: Option<f32>,
    /// Mass, friction and restitution of the objects the model was trained on; the server
    /// warns about requests outside them. Absent in older `config.json` files and in models
    /// not yet trained (no warning then).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trained_ranges: Option<TrainedRanges>,
}

/// The sizes a prepared scene's caches were built for (see [`ModelConfig::prepared_key`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PreparedKey {
    /// Anchors per object (K).
    pub anchors: usize,
    /// Set-abstraction centres per object.
    pub sa_centres: usize,
    /// Neighbours per set-abstraction centre.
    pub sa_neighbours: usize,
}

impl ModelConfig {
    /// The CPU-trainable configuration (width 128, 4 heads of 32, 6 blocks, 8 registers, K = 8,
    /// 32 centres x 8 neighbours in the encoder).
    pub fn small() -> ModelConfig {
        ModelConfig {
            architecture: RIGIDFORMER.into(),
            format_version: FORMAT_VERSION,
            dt_frame: 1.0 / 24.0,
            gravity: [0.0, 0.0, -10.0],
            points_per_object: 512,
            max_points_per_object: 8192,
            max_objects: 1024,
            contact_radius: 0.25,
            ground_z: Some(0.0),
            normalization: FeatureNormalization::defaults_for(&DynamicsConfig::residual()),
            position_scale: 0.5,
            point_dim: 32,
            sa_centres: 32,
            sa_neighbours: 8,
            sa_dim: 64,
            width: 128,
            heads: 4,
            blocks: 6,
            registers: 8,
            ffn_hidden: 512,
            film_hidden: 32,
            rope_dim: 24,
            rope_freq_min: 0.5,
            rope_freq_max: 16.0,
            norm_eps: 1e-6,
            anchors: 8,
            avp_sigma: 0.2,
            anchor_taps: vec![1, 3, 5],
            accel_scale: 0.02,
            accel_coarse_scale: None,
            loss: LossConfig::default(),
            dynamics: DynamicsConfig::residual(),
            floor_projection: None,
            trained_ranges: None,
        }
    }

    /// The paper's main configuration (width 256, 8 heads of 32, SwiGLU 4x, 8 blocks,
    /// 16 registers, K = 8; encoder 32 centres x 16 neighbours).
    pub fn paper() -> ModelConfig {
        ModelConfig {
            sa_neighbours: 16,
            width: 256,
            heads: 8,
            blocks: 8,
            registers: 16,
            ffn_hidden: 1024,
            anchor_taps: vec![1, 3, 5, 7],
            ..ModelConfig::small()
        }
    }

    /// A very small configuration for tests (width 32, 2 heads, 2 blocks).
    pub fn tiny() -> ModelConfig {
        ModelConfig {
            point_dim: 16,
            sa_centres: 8,
            sa_neighbours: 8,
            sa_dim: 16,
            width: 32,
            heads: 2,
            blocks: 2,
            registers: 2,
            ffn_hidden: 64,
            film_hidden: 8,
            rope_dim: 12,
            anchors: 4,
            anchor_taps: vec![0, 1],
            ..ModelConfig::small()
        }
    }

    /// What a prepared scene depends on: `(anchors, sa_centres, sa_neighbours)`. A scene
    /// prepared by one model steps on any model with the same key.
    pub fn prepared_key(&self) -> PreparedKey {
        PreparedKey {
            anchors: self.anchors,
            sa_centres: self.sa_centres,
            sa_neighbours: self.sa_neighbours,
        }
    }

    /// The first setting (its `config.json` name) in which `other` serves scenes differently
    /// from `self`, or `None`: the frame interval, gravity and ground, the request limits and
    /// nominal point count, the scene-relative mass, whether normals are estimated and whether
    /// the caller leads kinematic objects. Two such models can step one scene from one state,
    /// each from its own preparation when their [`PreparedKey`]s (anchor and grouping sizes)
    /// differ; their sizes, input features, normalisation and loss may differ too.
    pub fn serving_mismatch(&self, other: &ModelConfig) -> Option<&'static str> {
        let (a, b) = (&self.dynamics, &other.dynamics);
        [
            ("dt_frame", self.dt_frame == other.dt_frame),
            ("gravity", self.gravity == other.gravity),
            ("ground_z", self.ground_z == other.ground_z),
            (
                "points_per_object",
                self.points_per_object == other.points_per_object,
            ),
            (
                "max_points_per_object",
                self.max_points_per_object == other.max_points_per_object,
            ),
            ("max_objects", self.max_objects == other.max_objects),
            ("dynamics.relative_mass", a.relative_mass == b.relative_mass),
            (
                "dynamics.surface_normals or dynamics.approach (normals estimated)",
                a.reads_normals() == b.reads_normals(),
            ),
            (
                "dynamics.kinematic_lead",
                a.kinematic_lead == b.kinematic_lead,
            ),
        ]
        .into_iter()
        .find_map(|(name, same)| (!same).then_some(name))
    }

    /// Number of per-point input features (see [`DynamicsConfig::point_features`]).
    pub fn point_features(&self) -> usize {
        self.dynamics.point_features()
    }

    /// Width of one attention head.
    pub fn head_dim(&self) -> usize {
        self.width / self.heads.max(1)
    }

    /// Checks internal consistency; every violation is named.
    pub fn validate(&self) -> Result<(), ModelError> {
        let bad = |m: String| Err(ModelError::Checkpoint(format!("config.json: {m}")));
        if self.architecture != RIGIDFORMER {
            return bad(format!(
                "architecture {:?} is not supported (expected {RIGIDFORMER:?})",
                self.architecture
            ));
        }
        if self.format_version != FORMAT_VERSION {
            return bad(format!(
                "format_version {} is not supported (expected {FORMAT_VERSION})",
                self.format_version
            ));
        }
        let positive = [
            ("points_per_object", self.points_per_object),
            ("max_points_per_object", self.max_points_per_object),
            ("max_objects", self.max_objects),
            ("point_dim", self.point_dim),
            ("sa_centres", self.sa_centres),
            ("sa_neighbours", self.sa_neighbours),
            ("sa_dim", self.sa_dim),
            ("width", self.width),
            ("heads", self.heads),
            ("blocks", self.blocks),
            ("ffn_hidden", self.ffn_hidden),
            ("film_hidden", self.film_hidden),
            ("anchors", self.anchors),
        ];
        for (name, v) in positive {
            if v == 0 {
                return bad(format!("{name} must be > 0"));
            }
        }
        if !self.width.is_multiple_of(self.heads) {
            return bad(format!(
                "width {} is not divisible by heads {}",
                self.width, self.heads
            ));
        }
        if !self.rope_dim.is_multiple_of(6) || self.rope_dim > self.head_dim() {
            return bad(format!(
                "rope_dim {} must be a multiple of 6 and at most the head width {}",
                self.rope_dim,
                self.head_dim()
            ));
        }
        let finite_pos = [
            ("dt_frame", self.dt_frame),
            ("contact_radius", self.contact_radius),
            ("position_scale", self.position_scale),
            ("rope_freq_min", self.rope_freq_min),
            ("rope_freq_max", self.rope_freq_max),
            ("norm_eps", self.norm_eps),
            ("avp_sigma", self.avp_sigma),
            ("accel_scale", self.accel_scale),
            (
                "accel_coarse_scale",
                self.accel_coarse_scale.unwrap_or(self.accel_scale),
            ),
            ("loss.beta", self.loss.beta),
            ("loss.scale", self.loss.scale),
            ("loss.rest_weight", self.loss.rest_weight),
            (
                "loss.object_contact_weight",
                self.loss.object_contact_weight,
            ),
        ];
        for (name, v) in finite_pos {
            if !(v.is_finite() && v > 0.0) {
                return bad(format!("{name} must be finite and > 0, got {v}"));
            }
        }
        let w = self.loss.rotation_weight;
        if !(w.is_finite() && w >= 0.0) {
            return bad(format!(
                "loss.rotation_weight must be finite and >= 0, got {w}"
            ));
        }
        if self.rope_freq_max < self.rope_freq_min {
            return bad("rope_freq_max must be >= rope_freq_min".into());
        }
        if self.anchor_taps.is_empty() {
            return bad("anchor_taps must name at least one block".into());
        }
        if let Some(&t) = self.anchor_taps.iter().find(|&&t| t >= self.blocks) {
            return bad(format!(
                "anchor_taps entry {t} is not a block index (blocks = {})",
                self.blocks
            ));
        }
        let features = self.point_features();
        if self.normalization.mean.len() != features || self.normalization.std.len() != features {
            return bad(format!(
                "normalization: {} means and {} stds, the features need {features} of each",
                self.normalization.mean.len(),
                self.normalization.std.len()
            ));
        }
        if self
            .normalization
            .std
            .iter()
            .any(|s| !(s.is_finite() && *s > 0.0))
            || self.normalization.mean.iter().any(|m| !m.is_finite())
        {
            return bad("normalization: means must be finite and stds finite and > 0".into());
        }
        if self.gravity.iter().any(|g| !g.is_finite())
            || self.ground_z.is_some_and(|z| !z.is_finite())
            || self
                .loss
                .weights
                .iter()
                .any(|w| !(w.is_finite() && *w >= 0.0))
        {
            return bad("gravity, ground_z and loss.weights must be finite".into());
        }
        if self
            .floor_projection
            .is_some_and(|d| !(d.is_finite() && d >= 0.0))
        {
            return bad("floor_projection must be a finite depth >= 0 metres".into());
        }
        if let Some(r) = &self.trained_ranges {
            r.validate()
                .map_err(|m| ModelError::Checkpoint(format!("config.json: {m}")))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_round_trip() {
        for c in [
            ModelConfig::small(),
            ModelConfig::paper(),
            ModelConfig::tiny(),
        ] {
            c.validate().unwrap();
            let s = serde_json::to_string_pretty(&c).unwrap();
            let back: ModelConfig = serde_json::from_str(&s).unwrap();
            assert_eq!(back, c);
        }
        assert_eq!(ModelConfig::paper().head_dim(), 32);
    }

    /// `configs/small.json` and `configs/paper.json` are the presets; set
    /// `DYNASERVE_BLESS_CONFIGS=1` to rewrite them after changing a preset.
    #[test]
    fn shipped_config_files_match_presets() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs");
        for (name, preset) in [
            ("small", ModelConfig::small()),
            ("paper", ModelConfig::paper()),
        ] {
            let path = dir.join(format!("{name}.json"));
            if std::env::var_os("DYNASERVE_BLESS_CONFIGS").is_some() {
                let text = serde_json::to_string_pretty(&preset).unwrap() + "\n";
                std::fs::write(&path, text).unwrap();
            }
            let text = std::fs::read_to_string(&path).unwrap();
            let parsed: ModelConfig = serde_json::from_str(&text).unwrap();
            assert_eq!(
                parsed,
                preset,
                "{} differs from ModelConfig::{name}()",
                path.display()
            );
        }
    }

    #[test]
    fn invalid_configs_are_named() {
        let mut c = ModelConfig::small();
        c.heads = 3;
        assert!(c.validate().unwrap_err().to_string().contains("heads"));
        let mut c = ModelConfig::small();
        c.anchor_taps = vec![9];
        assert!(
            c.validate()
                .unwrap_err()
                .to_string()
                .contains("anchor_taps")
        );
        let mut c = ModelConfig::small();
        c.dynamics.contact_velocity = false;
        assert!(
            c.validate()
                .unwrap_err()
                .to_string()
                .contains("the features need 12")
        );
    }

    /// A `config.json` written before the contact velocity (no such key, 12 constants) reads
    /// as a 12-feature model.
    #[test]
    fn input_groups_sit_after_the_base_features_in_layout_order() {
        let mut d = DynamicsConfig::default();
        assert_eq!(InputGroup::SurfaceNormals.offset(&d), BASE_POINT_FEATURES);
        InputGroup::ContactVelocity.set(&mut d, true);
        assert!(d.contact_velocity);
        assert_eq!(InputGroup::ContactVelocity.offset(&d), BASE_POINT_FEATURES);
        assert_eq!(InputGroup::SurfaceNormals.offset(&d), 15);
        InputGroup::SurfaceNormals.set(&mut d, true);
        assert_eq!(d.point_features(), 22);
        assert_eq!(FeatureNormalization::defaults_for(&d).len(), 22);
    }

    #[test]
    fn configs_without_contact_velocity_read_as_twelve_features() {
        let mut old = serde_json::to_value(ModelConfig::small()).unwrap();
        let dynamics = old["dynamics"].as_object_mut().unwrap();
        dynamics.remove("contact_velocity");
        old["normalization"] = serde_json::to_value(FeatureNormalization::default()).unwrap();
        let c: ModelConfig = serde_json::from_value(old).unwrap();
        c.validate().unwrap();
        assert!(!c.dynamics.contact_velocity);
        assert_eq!(c.point_features(), 12);
        assert_eq!(ModelConfig::small().point_features(), 15);
    }
}
