//! The per-point input features shared by the model and the trainer's normalisation fit:
//! physical parameters, the frame features are measured from, the 12 base raw values, the
//! optional contact velocity, surface normals, history, approach and contact partner, and
//! [`ScenePoints`], the one place a scene's points are placed in the world, searched for
//! contacts and turned into raw features.

use dynaserve_geometry::{
    ContactConfig, ContactHit, ContactSource, DEFAULT_NORMAL_NEIGHBOURS, Point, contact_hits,
    estimate_normals,
};
use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use crate::api::Pose;
use crate::config::{
    APPROACH_FEATURES, BASE_POINT_FEATURES, CONTACT_PARTNER_FEATURES, CONTACT_PARTNER_MAX_LN_RATIO,
    CONTACT_SUMMARY_FEATURES, CONTACT_VELOCITY_FEATURES, DynamicsConfig, HISTORY_FEATURES,
    ModelConfig, OBJECT_SUMMARY_FEATURES, SURFACE_NORMAL_FEATURES,
};

/// Physical parameters as the model sees them: `[ln(mass / kg), friction, restitution]`.
pub fn object_params(mass: f32, friction: f32, restitution: f32) -> [f32; 3] {
    [mass.ln(), friction, restitution]
}

/// Where one object's point features are measured from, fixed by the model's
/// [`DynamicsConfig`], the step size and the object's current pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FeatureFrame {
    /// Subtracted from a point's world position before the reference offset, metres: the
    /// object's centre in x and y for translation-invariant inputs, else zero.
    pub origin: [f32; 3],
    /// The position increment over one step is divided by this (`k` for per-frame units).
    pub increment_divisor: f32,
}

impl FeatureFrame {
    /// The frame of an object whose centre of mass is at `translation` (metres), stepped by
    /// `dt_steps` frames.
    pub fn new(dynamics: &DynamicsConfig, dt_steps: u32, translation: [f32; 3]) -> FeatureFrame {
        FeatureFrame {
            origin: if dynamics.translation_invariant {
                [translation[0], translation[1], 0.0]
            } else {
                [0.0; 3]
            },
            increment_divisor: dynamics.increment_divisor(dt_steps),
        }
    }
}

/// The 12 raw (unnormalised) features of one point: contact displacement (m), position
/// increment over the last step `(x_t - x_{t-1}) / increment_divisor` (m), offset from the
/// reference `x_t - origin - x_ref` (m), and the object's [`object_params`]. The single
/// definition shared by the model and the trainer's normalisation fit.
pub fn raw_point_features(
    contact: [f32; 3],
    world: [f32; 3],
    world_prev: [f32; 3],
    reference: [f32; 3],
    params: [f32; 3],
    frame: &FeatureFrame,
) -> [f32; BASE_POINT_FEATURES] {
    let inc = 1.0 / frame.increment_divisor;
    let o = frame.origin;
    [
        contact[0],
        contact[1],
        contact[2],
        (world[0] - world_prev[0]) * inc,
        (world[1] - world_prev[1]) * inc,
        (world[2] - world_prev[2]) * inc,
        world[0] - o[0] - reference[0],
        world[1] - o[1] - reference[1],
        world[2] - o[2] - reference[2],
        params[0],
        params[1],
        params[2],
    ]
}

/// The contact velocity of point `q` of a scene, metres (per step divided by
/// `frame.increment_divisor`, like the increment feature): with `source` from the contact search
/// of `world`, the nearest other object's point's increment minus the point's own,
/// `(y_t - y_{t-1}) / d - (x_t - x_{t-1}) / d`; minus the own increment when the ground is the
/// contact (the ground is still); zero when nothing is within the contact radius.
/// `world` and `world_prev`: the scene's points at t and t-1, `[n, 3]` metres.
pub fn contact_velocity(
    source: ContactSource,
    q: usize,
    world: &[Point],
    world_prev: &[Point],
    frame: &FeatureFrame,
) -> [f32; CONTACT_VELOCITY_FEATURES] {
    let inc = 1.0 / frame.increment_divisor;
    let increment = |k: usize| [0, 1, 2].map(|d| (world[k][d] - world_prev[k][d]) * inc);
    match source {
        ContactSource::Point(j) => {
            let (other, own) = (increment(j as usize), increment(q));
            [0, 1, 2].map(|d| other[d] - own[d])
        }
        ContactSource::Ground => increment(q).map(|v| -v),
        ContactSource::Free => [0.0; 3],
    }
}

/// The contact partner features of point `q` of a scene ([`CONTACT_PARTNER_FEATURES`]): with
/// `source` from the contact search, `offsets` the first point of each object (`[objects + 1]`)
/// and `params` each object's [`object_params`], `[1, ln m_other - ln m_own, friction,
/// restitution]` of the object that `source` reaches, the mass ratio clamped to
/// [`CONTACT_PARTNER_MAX_LN_RATIO`]; zeros for the ground, for nothing within the contact
/// radius, and when `params` does not cover the objects.
pub fn contact_partner_features(
    source: ContactSource,
    q: usize,
    offsets: &[usize],
    params: &[[f32; 3]],
) -> [f32; CONTACT_PARTNER_FEATURES] {
    let object_of = |point: usize| offsets.partition_point(|&first| first <= point) - 1;
    match source {
        ContactSource::Point(j) => {
            let (own, other) = (object_of(q), object_of(j as usize));
            match (params.get(own), params.get(other)) {
                (Some(own), Some(other)) => [
                    1.0,
                    (other[0] - own[0])
                        .clamp(-CONTACT_PARTNER_MAX_LN_RATIO, CONTACT_PARTNER_MAX_LN_RATIO),
                    other[1],
                    other[2],
                ],
                _ => [0.0; CONTACT_PARTNER_FEATURES],
            }
        }
        ContactSource::Ground | ContactSource::Free => [0.0; CONTACT_PARTNER_FEATURES],
    }
}

/// Body-frame outward normals of one object's reference cloud (`[n, 3]` metres in, `[n, 3]`
/// unit vectors out), as [`DynamicsConfig::surface_normals`] uses them: the flattest of the
/// planes fitted to each point's 4, 6 and [`DEFAULT_NORMAL_NEIGHBOURS`] nearest points, signed
/// away from the centroid ([`estimate_normals`]). A cloud the estimator refuses (empty or not finite; validation
/// refuses both first) gets `+z` everywhere.
pub fn body_normals(reference: &[Point]) -> Vec<Point> {
    estimate_normals(reference, DEFAULT_NORMAL_NEIGHBOURS)
        .unwrap_or_else(|_| vec![[0.0, 0.0, 1.0]; reference.len()])
}

/// The surface normal features of point `q` of a scene ([`DynamicsConfig::surface_normals`]):
/// its own world normal `normals[q]` (3), the normal of the surface its contact `hit` reaches
/// (3: the nearest other point's world normal, `+z` for the ground, zero when nothing is within
/// the contact radius) and its signed height above that surface's tangent plane, metres (1:
/// minus the contact displacement along that normal, negative behind the plane; `radius` when
/// nothing is near; heights clamped to +-`radius`). `normals`: every point's unit normal at t,
/// `[n, 3]`; a point missing from it reads as a zero normal.
pub fn surface_normal_features(
    hit: &ContactHit,
    q: usize,
    normals: &[Point],
    radius: f32,
) -> [f32; SURFACE_NORMAL_FEATURES] {
    let normal = |i: usize| normals.get(i).copied().unwrap_or([0.0; 3]);
    let own = normal(q);
    let (other, gap) = match hit.source {
        ContactSource::Point(j) => {
            let m = normal(j as usize);
            let along: f32 = (0..3).map(|d| hit.displacement[d] * m[d]).sum();
            (m, (-along).clamp(-radius, radius))
        }
        ContactSource::Ground => (
            [0.0, 0.0, 1.0],
            (-hit.displacement[2]).clamp(-radius, radius),
        ),
        ContactSource::Free => ([0.0; 3], radius),
    };
    [own[0], own[1], own[2], other[0], other[1], other[2], gap]
}

/// The history features of one point ([`DynamicsConfig::history`]): how its motion changed
/// over the previous step beyond free fall, `(x_t - 2 x_{t-k} + x_{t-2k} - fall) / d^2` with
/// `d = frame.increment_divisor` (metres per frame^2 with per-frame units). `world`,
/// `world_prev` and `world_earlier`: the point at t, t - k and t - 2k, metres; `fall`: free
/// fall over one step, `g (k dt_frame)^2`, metres. Zero for a body in free flight (up to its
/// spin's centripetal term); a point whose earlier pose is unknown reads zero as well
/// ([`ScenePoints::raw_features`]), not this of any pose.
pub fn history_features(
    world: Point,
    world_prev: Point,
    world_earlier: Point,
    fall: [f32; 3],
    frame: &FeatureFrame,
) -> [f32; HISTORY_FEATURES] {
    let inv = 1.0 / (frame.increment_divisor * frame.increment_divisor);
    [0, 1, 2].map(|d| (world[d] - 2.0 * world_prev[d] + world_earlier[d] - fall[d]) * inv)
}

/// The approach features of one point ([`DynamicsConfig::approach`]) from its
/// [`contact_velocity`] `cv` and its [`surface_normal_features`] `normals` (the surface its
/// contact reaches: that surface's normal at `[3..6]`, the point's height above its tangent
/// plane at `[6]`, metres), with `divisor = frame.increment_divisor`:
/// `[closing, reach, depth]`. `closing = cv . m` is the speed at which the point nears the
/// surface along its normal `m` (metres per step divided by `divisor`, positive when
/// approaching); over the step it travels `closing * divisor` towards a surface `gap` away.
/// `reach` is the fraction of the step before it gets there, `gap / (closing * divisor)` in
/// [0, 1] (0 when it is already at or behind the surface, 1 when it does not get there within
/// the step or recedes); `depth` how far behind the surface the step would end,
/// `max(0, closing * divisor - gap) / divisor`, at most `radius / divisor`. A point with no
/// surface within the contact radius (a zero normal) reads `[0, 1, 0]`.
pub fn approach_features(
    cv: [f32; CONTACT_VELOCITY_FEATURES],
    normals: &[f32; SURFACE_NORMAL_FEATURES],
    radius: f32,
    frame: &FeatureFrame,
) -> [f32; APPROACH_FEATURES] {
    let m = [normals[3], normals[4], normals[5]];
    if m == [0.0; 3] {
        return [0.0, 1.0, 0.0];
    }
    let gap = normals[6];
    let d = frame.increment_divisor;
    let closing = cv[0] * m[0] + cv[1] * m[1] + cv[2] * m[2];
    let travel = closing * d;
    let reach = if gap <= 0.0 {
        0.0
    } else if travel > gap {
        gap / travel
    } else {
        1.0
    };
    let depth = (travel - gap).clamp(0.0, radius) / d;
    [closing, reach, depth]
}

/// Heights in the object summary are divided by this, metres.
pub const SUMMARY_HEIGHT_SCALE: f32 = 0.5;
/// Heights in the object summary are clamped to this before scaling, metres: a body far above
/// the floor (or a scene without one) reads as this high.
pub const SUMMARY_HEIGHT_MAX: f32 = 4.0;
/// Increments in the object summary (per frame with per-frame units) are divided by this,
/// metres.
pub const SUMMARY_INCREMENT_SCALE: f32 = 0.1;
/// The rotation increment in the object summary (per frame with per-frame units) is divided
/// by this, radians.
pub const SUMMARY_ROTATION_SCALE: f32 = 0.2;
/// The lowest point's offset from the centre in the object summary is divided by this, metres.
pub const SUMMARY_LEVER_SCALE: f32 = 0.2;

/// The object state summary of one object ([`DynamicsConfig::object_summary`]), scaled to O(1):
/// `[h_low, inc_low (3), h_centre, inc_centre (3), rotation (3), lever (3)]`. `h_low` is the
/// height of its lowest point above `ground_z` and `h_centre` its centre's (metres, clamped to
/// [`SUMMARY_HEIGHT_MAX`], divided by [`SUMMARY_HEIGHT_SCALE`]; without a ground both read as
/// the maximum); `inc_low` and `inc_centre` the increments of that point and of the centre over
/// the last step divided by `frame.increment_divisor` (divided by
/// [`SUMMARY_INCREMENT_SCALE`]); `rotation` the scaled axis of `R_t R_{t-k}^T` divided by the
/// same divisor (divided by [`SUMMARY_ROTATION_SCALE`]); `lever` the lowest point minus the
/// centre, world frame (divided by [`SUMMARY_LEVER_SCALE`]): where a landing body touches
/// relative to its centre of mass, which decides how the impact turns it.
/// `world` and `world_prev`: the object's points at t and t-1 (`[n, 3]` metres, `n >= 1`).
pub fn object_summary(
    world: &[Point],
    world_prev: &[Point],
    current: &Pose,
    previous: &Pose,
    ground_z: Option<f32>,
    frame: &FeatureFrame,
) -> [f32; OBJECT_SUMMARY_FEATURES] {
    let inc = 1.0 / frame.increment_divisor;
    let height = |z: f32| match ground_z {
        Some(g) => (z - g).min(SUMMARY_HEIGHT_MAX),
        None => SUMMARY_HEIGHT_MAX,
    } / SUMMARY_HEIGHT_SCALE;
    let (now, before) = (current.translation, previous.translation);
    let turn = (current.unit_quaternion() * previous.unit_quaternion().inverse()).scaled_axis();
    let mut out = [0f32; OBJECT_SUMMARY_FEATURES];
    let low =
        (0..world.len().min(world_prev.len())).min_by(|&a, &b| world[a][2].total_cmp(&world[b][2]));
    out[0] = low.map_or(SUMMARY_HEIGHT_MAX / SUMMARY_HEIGHT_SCALE, |i| {
        height(world[i][2])
    });
    for d in 0..3 {
        if let Some(i) = low {
            out[1 + d] = (world[i][d] - world_prev[i][d]) * inc / SUMMARY_INCREMENT_SCALE;
            out[11 + d] = (world[i][d] - now[d]) / SUMMARY_LEVER_SCALE;
        }
        out[5 + d] = (now[d] - before[d]) * inc / SUMMARY_INCREMENT_SCALE;
        out[8 + d] = turn[d] * inc / SUMMARY_ROTATION_SCALE;
    }
    out[4] = height(now[2]);
    out
}

/// Points of an object within this distance (metres) beyond its nearest gap to another
/// object count towards the contact summary's patch, with weights falling off on this scale.
pub const CONTACT_PATCH_SCALE: f32 = 0.02;

/// The smallest distance from an object's points (`points`, its rows in the scene's `hits`)
/// to another object's point, metres: the shortest contact displacement that reaches another
/// object, not the ground; infinite when none is within the contact radius.
pub fn nearest_object_gap(hits: &[ContactHit], points: std::ops::Range<usize>) -> f32 {
    hits[points]
        .iter()
        .filter(|h| matches!(h.source, ContactSource::Point(_)))
        .map(|h| h.displacement.iter().map(|d| d * d).sum::<f32>())
        .fold(f32::INFINITY, f32::min)
        .sqrt()
}

/// The contact summary of one object ([`DynamicsConfig::contact_summary`]), scaled to O(1):
/// `[gap, direction (3), lever (3), velocity (3), share]`. Only points whose contact search
/// reached another object's point count (not the ground's). `gap` is `nearest`, the object's
/// [`nearest_object_gap`], clamped to `radius` and divided by it (1 when no point reaches
/// another object; everything else is then zero). Over the patch of points within
/// `3 CONTACT_PATCH_SCALE` of that gap, each weighted by `exp(-(g - nearest) /
/// CONTACT_PATCH_SCALE)`: `direction` is the weighted mean unit vector towards the other
/// surface, `lever` the weighted mean offset of the points from `centre` (world frame, divided
/// by [`SUMMARY_LEVER_SCALE`]): where the object is touched relative to its centre of mass,
/// which decides how an impact turns it; `velocity` the weighted mean [`contact_velocity`]
/// (divided by [`SUMMARY_INCREMENT_SCALE`]); `share` the weights' sum over the object's
/// point count, how much of it touches. `hits`, `world` and `world_prev`: the whole scene's,
/// `[n]` and `[n, 3]` metres; `points`: this object's rows in them; `centre`: its centre of
/// mass at t, metres.
#[allow(clippy::too_many_arguments)]
pub fn contact_summary(
    hits: &[ContactHit],
    world: &[Point],
    world_prev: &[Point],
    points: std::ops::Range<usize>,
    centre: [f32; 3],
    nearest: f32,
    radius: f32,
    frame: &FeatureFrame,
) -> [f32; CONTACT_SUMMARY_FEATURES] {
    let mut out = [0f32; CONTACT_SUMMARY_FEATURES];
    if !nearest.is_finite() {
        out[0] = 1.0;
        return out;
    }
    out[0] = nearest.min(radius) / radius;
    let mut total = 0.0;
    for q in points.clone() {
        let hit = &hits[q];
        if !matches!(hit.source, ContactSource::Point(_)) {
            continue;
        }
        let d = hit.displacement;
        let g = d.iter().map(|v| v * v).sum::<f32>().sqrt();
        if g > nearest + 3.0 * CONTACT_PATCH_SCALE {
            continue;
        }
        let w = (-(g - nearest) / CONTACT_PATCH_SCALE).exp();
        let v = contact_velocity(hit.source, q, world, world_prev, frame);
        for a in 0..3 {
            if g > 0.0 {
                out[1 + a] += w * d[a] / g;
            }
            out[4 + a] += w * (world[q][a] - centre[a]) / SUMMARY_LEVER_SCALE;
            out[7 + a] += w * v[a] / SUMMARY_INCREMENT_SCALE;
        }
        total += w;
    }
    for v in &mut out[1..10] {
        *v /= total;
    }
    out[10] = total / points.len().max(1) as f32;
    out
}

/// A pose as the rotation matrix and translation (metres) points are moved with.
pub(crate) fn rotation_translation(p: &Pose) -> (Matrix3<f32>, Vector3<f32>) {
    let [x, y, z, w] = p.rotation;
    let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
    (
        q.to_rotation_matrix().into_inner(),
        Vector3::from(p.translation),
    )
}

/// One object as its points' features read it ([`ScenePoints::for_model`]).
#[derive(Clone, Copy, Debug)]
pub struct Body<'a> {
    /// Its reference cloud, body frame, `[n, 3]` metres.
    pub reference: &'a [Point],
    /// Its [`object_params`] as the model sees them (with scene-relative mass, the relative
    /// mass).
    pub params: [f32; 3],
}

/// A scene's points in the world at t and t-1 (and t-2 when known), object after object, with
/// every point's contact hit: what the raw point features of one step are measured on.
#[derive(Clone, Debug)]
pub struct ScenePoints {
    /// Every point at t, `[n, 3]` metres.
    pub world: Vec<Point>,
    /// Every point at t-1, `[n, 3]` metres.
    pub world_prev: Vec<Point>,
    /// First point of each object, `[objects + 1]`.
    pub offsets: Vec<usize>,
    /// The contact search's result per point, `[n]` (radius and ground from the model).
    pub contact: Vec<ContactHit>,
    /// Every point's outward unit normal at t, `[n, 3]`, when the model reads surface normals
    /// ([`ScenePoints::with_normals`]); empty otherwise.
    pub normals: Vec<Point>,
    /// Every point one step before t - 1, `[n, 3]` metres, when the model reads the history
    /// and the earlier poses are known ([`ScenePoints::with_history`]); empty otherwise, which
    /// reads as zero history features.
    pub world_earlier: Vec<Point>,
    /// Free fall over one step, `g (k dt_frame)^2` metres, set with `world_earlier`.
    fall: [f32; 3],
    /// Each object's [`object_params`] as the model sees them, `[objects]`, when the model
    /// reads the contact partner ([`ScenePoints::with_object_params`]); empty otherwise, which
    /// reads as zero contact partner features.
    pub object_params: Vec<[f32; 3]>,
    /// The model's contact radius, metres.
    radius: f32,
}

impl ScenePoints {
    /// Places the reference cloud of each object (body frame, metres) at its `current` and
    /// `previous` pose and runs the contact search with `cfg`'s radius and ground height.
    pub fn new<'a>(
        cfg: &ModelConfig,
        references: impl IntoIterator<Item = &'a [Point]>,
        current: &[Pose],
        previous: &[Pose],
    ) -> ScenePoints {
        let mut offsets = vec![0usize];
        let mut world = Vec::new();
        let mut world_prev = Vec::new();
        for ((reference, now), before) in references.into_iter().zip(current).zip(previous) {
            let (rc, pc) = rotation_translation(now);
            let (rp, pp) = rotation_translation(before);
            for x in reference {
                let xv = Vector3::from(*x);
                let a = rc * xv + pc;
                let b = rp * xv + pp;
                world.push([a.x, a.y, a.z]);
                world_prev.push([b.x, b.y, b.z]);
            }
            offsets.push(world.len());
        }
        let contact = contact_hits(
            &world,
            &offsets,
            &ContactConfig {
                radius: cfg.contact_radius,
                ground_z: cfg.ground_z,
            },
        );
        ScenePoints {
            world,
            world_prev,
            offsets,
            contact,
            normals: Vec::new(),
            world_earlier: Vec::new(),
            fall: [0.0; 3],
            object_params: Vec::new(),
            radius: cfg.contact_radius,
        }
    }

    /// Adds each object's [`object_params`] (`[objects]`, in the clouds' order, as the model
    /// sees them: with scene-relative mass, the relative masses). Needed by
    /// [`ScenePoints::raw_features`] for non-zero contact partner features.
    pub fn with_object_params(mut self, params: Vec<[f32; 3]>) -> ScenePoints {
        self.object_params = params;
        self
    }

    /// The points a model with `cfg` reads for one step: [`ScenePoints::new`] on the bodies'
    /// clouds, then the surface normals ([`ScenePoints::with_normals`]), the history
    /// ([`ScenePoints::with_history`], when `earlier` poses are known) and the objects'
    /// parameters ([`ScenePoints::with_object_params`]) that its dynamics switches ask for.
    /// `normals` gives each object's body-frame normals (`[n, 3]` unit vectors in the bodies'
    /// order) and is called only when the model reads them.
    pub fn for_model<N: AsRef<[Point]>>(
        cfg: &ModelConfig,
        bodies: &[Body<'_>],
        normals: impl FnOnce() -> Vec<N>,
        current: &[Pose],
        previous: &[Pose],
        earlier: Option<&[Pose]>,
        dt_steps: u32,
    ) -> ScenePoints {
        let references = || bodies.iter().map(|b| b.reference);
        let mut points = ScenePoints::new(cfg, references(), current, previous);
        if cfg.dynamics.reads_normals() {
            let body = normals();
            points = points.with_normals(body.iter().map(AsRef::as_ref), current);
        }
        if let (true, Some(earlier)) = (cfg.dynamics.history, earlier) {
            points = points.with_history(cfg, references(), earlier, dt_steps);
        }
        if cfg.dynamics.contact_partner {
            points = points.with_object_params(bodies.iter().map(|b| b.params).collect());
        }
        points
    }

    /// Adds every point's world position one step before t - 1: each object's `references`
    /// (body frame, metres, as given to [`ScenePoints::new`]) placed at its `earlier` pose.
    /// `dt_steps` is the step size in frames (for the free fall `cfg` gives). Needed by
    /// [`ScenePoints::raw_features`] for non-zero history features.
    pub fn with_history<'a>(
        mut self,
        cfg: &ModelConfig,
        references: impl IntoIterator<Item = &'a [Point]>,
        earlier: &[Pose],
        dt_steps: u32,
    ) -> ScenePoints {
        self.world_earlier = Vec::with_capacity(self.world.len());
        for (reference, before) in references.into_iter().zip(earlier) {
            let (r, p) = rotation_translation(before);
            for x in reference {
                let w = r * Vector3::from(*x) + p;
                self.world_earlier.push([w.x, w.y, w.z]);
            }
        }
        let h = dt_steps.max(1) as f32 * cfg.dt_frame;
        self.fall = cfg.gravity.map(|g| g * h * h);
        self
    }

    /// Adds every point's world normal at t: each object's body-frame normals (`[n, 3]` unit
    /// vectors, in the reference clouds' order, e.g. [`body_normals`]) turned by its `current`
    /// pose. Needed by [`ScenePoints::raw_features`] when the model reads surface normals.
    pub fn with_normals<'a>(
        mut self,
        body: impl IntoIterator<Item = &'a [Point]>,
        current: &[Pose],
    ) -> ScenePoints {
        self.normals = Vec::with_capacity(self.world.len());
        for (normals, now) in body.into_iter().zip(current) {
            let (rc, _) = rotation_translation(now);
            for m in normals {
                let w = rc * Vector3::from(*m);
                self.normals.push([w.x, w.y, w.z]);
            }
        }
        self
    }

    /// Writes the raw (unnormalised) features of point `q` of the scene into `out`: the
    /// [`raw_point_features`] of its `reference` position (body frame, metres) and its
    /// object's `params`, then the optional ones `dynamics` selects: its [`contact_velocity`],
    /// its [`surface_normal_features`] (which need [`ScenePoints::with_normals`]), its
    /// [`history_features`] (zero without [`ScenePoints::with_history`]), its
    /// [`approach_features`] (which need [`ScenePoints::with_normals`]) and its
    /// [`contact_partner_features`] (zero without [`ScenePoints::with_object_params`]).
    /// `out` holds [`DynamicsConfig::point_features`] values.
    pub fn raw_features(
        &self,
        q: usize,
        reference: Point,
        params: [f32; 3],
        frame: &FeatureFrame,
        dynamics: &DynamicsConfig,
        out: &mut [f32],
    ) {
        let hit = self.contact[q];
        out[..BASE_POINT_FEATURES].copy_from_slice(&raw_point_features(
            hit.displacement,
            self.world[q],
            self.world_prev[q],
            reference,
            params,
            frame,
        ));
        let mut at = BASE_POINT_FEATURES;
        // Each computed once per point, for its own group and for the approach.
        let cv = (dynamics.contact_velocity || dynamics.approach)
            .then(|| contact_velocity(hit.source, q, &self.world, &self.world_prev, frame));
        let normals = dynamics
            .reads_normals()
            .then(|| surface_normal_features(&hit, q, &self.normals, self.radius));
        if dynamics.contact_velocity
            && let Some(cv) = &cv
        {
            out[at..at + CONTACT_VELOCITY_FEATURES].copy_from_slice(cv);
            at += CONTACT_VELOCITY_FEATURES;
        }
        if dynamics.surface_normals
            && let Some(normals) = &normals
        {
            out[at..at + SURFACE_NORMAL_FEATURES].copy_from_slice(normals);
            at += SURFACE_NORMAL_FEATURES;
        }
        if dynamics.history {
            let history = match self.world_earlier.get(q) {
                Some(&earlier) => {
                    history_features(self.world[q], self.world_prev[q], earlier, self.fall, frame)
                }
                None => [0.0; HISTORY_FEATURES],
            };
            out[at..at + HISTORY_FEATURES].copy_from_slice(&history);
            at += HISTORY_FEATURES;
        }
        if dynamics.approach
            && let (Some(cv), Some(normals)) = (cv, &normals)
        {
            out[at..at + APPROACH_FEATURES].copy_from_slice(&approach_features(
                cv,
                normals,
                self.radius,
                frame,
            ));
            at += APPROACH_FEATURES;
        }
        if dynamics.contact_partner {
            out[at..at + CONTACT_PARTNER_FEATURES].copy_from_slice(&contact_partner_features(
                hit.source,
                q,
                &self.offsets,
                &self.object_params,
            ));
        }
    }
}
