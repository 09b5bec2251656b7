//! How a RigidFormer's inputs and outputs relate to the physics ([`DynamicsConfig`]): its
//! switches, the optional input groups ([`InputGroup`]) and network units ([`ModelUnit`]) they
//! turn on.

use serde::{Deserialize, Serialize};

use super::feature_layout::{
    APPROACH_FEATURES, BASE_POINT_FEATURES, CONTACT_PARTNER_FEATURES, CONTACT_VELOCITY_FEATURES,
    HISTORY_FEATURES, SURFACE_NORMAL_FEATURES,
};

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
    /// Object state summary: [`OBJECT_SUMMARY_FEATURES`](super::feature_layout::OBJECT_SUMMARY_FEATURES) numbers per object (the lowest
    /// point's height above the ground and increment, the centre's height and increment, the
    /// rotation increment, the lowest point's offset from the centre), added to the object's
    /// token through a small MLP whose last layer starts at zero, so the floor reaches the
    /// decoder without passing through the encoder's max-pools. Absent in older `config.json`
    /// files, which means off.
    pub object_summary: bool,
    /// Contact summary: [`CONTACT_SUMMARY_FEATURES`](super::feature_layout::CONTACT_SUMMARY_FEATURES) numbers per object describing where it
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
    /// ([`LN_MASS_FEATURE`](super::LN_MASS_FEATURE)). Rigid bodies under gravity and contact
    /// move the same under such a common factor, and the model then answers the same too: only
    /// mass ratios reach it. A kinematic body's mass moves nothing: it sets no scale and is seen
    /// as that mean. Absent in older `config.json` files, which means off.
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
