//! Contact regimes of the ground truth, per object and prediction window, and the one-step
//! error pooled per regime.
//!
//! A prediction window is the predictor's input and target, frames `t - k`, `t` and `t + k`;
//! contact is looked for over its whole span `t - k ..= t + k`. An object is, from the ground
//! truth (first match wins):
//! 1. **resting**: in contact (floor or object) during the span, and its centre speed is
//!    below [`RESTING_SPEED_M_S`] and its angular speed below [`RESTING_ANGULAR_DEG_S`] both at
//!    `t` and at `t + k` (backward differences over one frame);
//! 2. **object contact**: some frame of the span has one of its reference points within the
//!    scene's contact distance of a point of another object;
//! 3. **floor contact**: some frame of the span has its lowest reference point within its
//!    floor distance of the floor (z = 0);
//! 4. **free flight**: otherwise.
//!
//! A fast bounce can begin and end between two recorded frames, unseen by the distance tests.
//! So a frame `f` also counts as a contact when the centre's acceleration there,
//! `(p(f+1) - 2 p(f) + p(f-1)) / dt^2`, differs from gravity by more than
//! [`IMPULSE_ACCELERATION_M_S2`] (rapier's free flight gives exactly gravity, up to `f32`
//! rounding); such a contact without a nearby object or floor is a floor contact when the
//! object's lowest point came within one frame's travel of the floor during the span, an
//! object contact otherwise.
//!
//! Reference points are the stored clouds posed with the ground-truth poses. Because the
//! clouds are samples, two touching surfaces can be a sampling gap apart: the contact distance
//! between objects is [`CONTACT_DISTANCE_M`] plus the largest median nearest-neighbour spacing
//! of the scene's clouds, and the floor distance of an object is [`CONTACT_DISTANCE_M`] plus
//! half its own spacing.

use dynaserve_geometry::contact::{ContactConfig, contact_features};
use dynaserve_geometry::geodesic_angle;
use dynaserve_sim::SceneRecord;
use dynaserve_sim::stats::posed_cloud;
use serde::{Deserialize, Serialize};

use super::EvalError;

/// Base contact distance, metres.
pub const CONTACT_DISTANCE_M: f32 = 0.01;
/// Largest centre speed of a resting object, m/s.
pub const RESTING_SPEED_M_S: f64 = 0.05;
/// Largest angular speed of a resting object, degrees per second.
pub const RESTING_ANGULAR_DEG_S: f64 = 5.0;
/// Deviation of the centre's acceleration from gravity that reveals a contact between recorded
/// frames, m/s^2.
pub const IMPULSE_ACCELERATION_M_S2: f64 = 1.0;
/// Points per cloud used to estimate the sampling spacing.
const SPACING_SAMPLES: usize = 128;

/// What an object is doing during a prediction window (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Regime {
    /// No contact during the window.
    FreeFlight,
    /// Touching the floor, not another object.
    FloorContact,
    /// Touching another object.
    ObjectContact,
    /// In contact and still at both ends of the window.
    Resting,
    /// A floor-contact window in which the object is off the floor at `t` or at `t + k` (it
    /// lands, bounces or leaves within the window): a subset of [`Regime::FloorContact`],
    /// reported beside it ([`impact_subset`]), never returned by [`regime`]. Bounces are a few percent of the
    /// floor-contact windows and carry errors ten times the sustained contacts'.
    FloorImpact,
    /// An object-contact window in which the object is not touching another object (by the
    /// distance test) at `t` or at `t + k`: a contact begins, ends or comes and goes between
    /// recorded frames within the window. A subset of [`Regime::ObjectContact`], reported beside
    /// it ([`impact_subset`]), never returned by [`regime`].
    ObjectImpact,
}

impl Regime {
    /// The regimes a window is classified into, in report order.
    pub const ALL: [Regime; 4] = [
        Regime::FreeFlight,
        Regime::FloorContact,
        Regime::ObjectContact,
        Regime::Resting,
    ];

    /// Every row of the report, in order: [`Regime::ALL`] with the floor impacts after the
    /// floor contacts and the object impacts after the object contacts.
    pub const REPORTED: [Regime; 6] = [
        Regime::FreeFlight,
        Regime::FloorContact,
        Regime::FloorImpact,
        Regime::ObjectContact,
        Regime::ObjectImpact,
        Regime::Resting,
    ];

    /// Name used in reports.
    pub fn name(self) -> &'static str {
        match self {
            Regime::FreeFlight => "free flight",
            Regime::FloorContact => "floor contact",
            Regime::ObjectContact => "object contact",
            Regime::Resting => "resting",
            Regime::FloorImpact => "floor contact: impacts",
            Regime::ObjectImpact => "object contact: impacts",
        }
    }

    fn index(self) -> usize {
        self as usize
    }
}

/// Ground-truth contact flags of a scene, `[frames][objects]`.
#[derive(Clone, Debug, PartialEq)]
pub struct ContactFlags {
    /// The object's lowest reference point is within its floor distance of z = 0.
    pub floor: Vec<Vec<bool>>,
    /// A reference point of the object is within the contact distance of another object's.
    pub object: Vec<Vec<bool>>,
    /// The same within the looser impact distance [`ContactFlags::impact_distance_m`], which
    /// also catches touching surfaces whose sparse samples stay a few centimetres apart.
    pub near_object: Vec<Vec<bool>>,
    /// The centre's acceleration differs from gravity by more than
    /// [`IMPULSE_ACCELERATION_M_S2`] (false at the first and last frame).
    pub impulse: Vec<Vec<bool>>,
    /// Height of the object's lowest reference point, metres.
    pub lowest: Vec<Vec<f32>>,
    /// Contact distance between objects used for this scene, metres.
    pub object_distance_m: f32,
    /// Impact distance: [`CONTACT_DISTANCE_M`] plus three times the largest cloud spacing,
    /// metres.
    pub impact_distance_m: f32,
}

/// Median distance from a point of the cloud to its nearest neighbour in the cloud (over the
/// first 128 points), metres; 0 for clouds of fewer than 2 points.
pub fn sampling_spacing(cloud: &[[f32; 3]]) -> f32 {
    if cloud.len() < 2 {
        return 0.0;
    }
    let mut nearest: Vec<f32> = cloud
        .iter()
        .take(SPACING_SAMPLES)
        .enumerate()
        .map(|(i, a)| {
            cloud
                .iter()
                .enumerate()
                .filter(|(j, _)| *j != i)
                .map(|(_, b)| (0..3).map(|c| (a[c] - b[c]).powi(2)).sum::<f32>())
                .fold(f32::INFINITY, f32::min)
                .sqrt()
        })
        .collect();
    nearest.sort_by(f32::total_cmp);
    nearest[nearest.len() / 2]
}

/// Contact flags of every object at every frame of the ground truth, under `gravity` (m/s^2).
pub fn contact_flags(scene: &SceneRecord, gravity: [f32; 3]) -> Result<ContactFlags, EvalError> {
    let n = scene.objects.len();
    let frames = scene
        .objects
        .first()
        .map(|o| o.positions.len())
        .ok_or_else(|| EvalError::Invalid("scene without objects".into()))?;
    let spacing: Vec<f32> = scene
        .objects
        .iter()
        .map(|o| sampling_spacing(&o.reference_points))
        .collect();
    let widest = spacing.iter().copied().fold(0.0, f32::max);
    let radius = CONTACT_DISTANCE_M + widest;
    let loose = CONTACT_DISTANCE_M + 3.0 * widest;
    // The ground far below: never a candidate, so a point without a neighbour gets the
    // fallback (0, 0, -loose), at exactly the search radius.
    let cfg = ContactConfig {
        radius: loose,
        ground_z: Some(-1.0e6),
    };
    let mut floor = Vec::with_capacity(frames);
    let mut object = Vec::with_capacity(frames);
    let mut near_object = Vec::with_capacity(frames);
    let mut lowest = Vec::with_capacity(frames);
    for t in 0..frames {
        let mut points = Vec::new();
        let mut offsets = vec![0usize];
        let mut low = Vec::with_capacity(n);
        for j in 0..n {
            let cloud = posed_cloud(&scene.objects[j], t);
            low.push(cloud.iter().map(|p| p[2]).fold(f32::INFINITY, f32::min));
            points.extend(cloud);
            offsets.push(points.len());
        }
        floor.push(
            (0..n)
                .map(|j| low[j] < CONTACT_DISTANCE_M + 0.5 * spacing[j])
                .collect(),
        );
        lowest.push(low);
        // Squared distance from each object to the nearest point of another (capped).
        let gap: Vec<f32> = if n > 1 {
            let d = contact_features(&points, &offsets, &cfg);
            (0..n)
                .map(|j| {
                    d[offsets[j]..offsets[j + 1]]
                        .iter()
                        .map(|v| v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
                        .fold(f32::INFINITY, f32::min)
                })
                .collect()
        } else {
            vec![f32::INFINITY; n]
        };
        object.push(gap.iter().map(|g| *g < radius * radius).collect());
        near_object.push(gap.iter().map(|g| *g < loose * loose).collect());
    }
    let dt = f64::from(scene.dt_frame);
    let impulse = (0..frames)
        .map(|f| {
            scene
                .objects
                .iter()
                .map(|o| {
                    if f == 0 || f + 1 >= frames {
                        return false;
                    }
                    let (a, b, c) = (o.positions[f - 1], o.positions[f], o.positions[f + 1]);
                    let dev = (0..3)
                        .map(|x| {
                            let acc = (f64::from(c[x]) - 2.0 * f64::from(b[x]) + f64::from(a[x]))
                                / (dt * dt);
                            (acc - f64::from(gravity[x])).powi(2)
                        })
                        .sum::<f64>()
                        .sqrt();
                    dev > IMPULSE_ACCELERATION_M_S2
                })
                .collect()
        })
        .collect();
    Ok(ContactFlags {
        floor,
        object,
        near_object,
        impulse,
        lowest,
        object_distance_m: radius,
        impact_distance_m: loose,
    })
}

/// Centre speed (m/s) and angular speed (deg/s) of object `j` between frames `t - 1` and `t`.
fn speeds(scene: &SceneRecord, j: usize, t: usize) -> (f64, f64) {
    let o = &scene.objects[j];
    let dt = f64::from(scene.dt_frame);
    let (a, b) = (o.positions[t - 1], o.positions[t]);
    let v = (0..3)
        .map(|c| (f64::from(b[c]) - f64::from(a[c])).powi(2))
        .sum::<f64>()
        .sqrt()
        / dt;
    let w = geodesic_angle(o.rotations[t - 1], o.rotations[t]).to_degrees() / dt;
    (v, w)
}

/// The regime of object `j` during the window `t - k, t -> t + k` (`1 <= t`, `t + k` a
/// frame).
pub fn regime(scene: &SceneRecord, flags: &ContactFlags, j: usize, t: usize, k: usize) -> Regime {
    let (on_object, on_floor) = touched(scene, flags, j, t.saturating_sub(k)..=t + k);
    let still = |f: usize| {
        let (v, w) = speeds(scene, j, f);
        v < RESTING_SPEED_M_S && w < RESTING_ANGULAR_DEG_S
    };
    if (on_object || on_floor) && still(t) && still(t + k) {
        Regime::Resting
    } else if on_object {
        Regime::ObjectContact
    } else if on_floor {
        Regime::FloorContact
    } else {
        Regime::FreeFlight
    }
}

/// Whether object `j` touched another object and whether it touched the floor during the
/// frames `span` (the module's distance tests, and its impulse test for a contact between two
/// frames).
pub fn touched(
    scene: &SceneRecord,
    flags: &ContactFlags,
    j: usize,
    span: std::ops::RangeInclusive<usize>,
) -> (bool, bool) {
    let mut on_object = span.clone().any(|f| flags.object[f][j]);
    let mut on_floor = span.clone().any(|f| flags.floor[f][j]);
    if !(on_object || on_floor) && span.clone().any(|f| flags.impulse[f][j]) {
        // Unseen contact: the floor if the object came within a frame's travel of it.
        let reach = span
            .clone()
            .filter(|&f| f >= 1)
            .map(|f| speeds(scene, j, f).0 * f64::from(scene.dt_frame))
            .fold(0.0, f64::max);
        let low = span
            .clone()
            .map(|f| f64::from(flags.lowest[f][j]))
            .fold(f64::INFINITY, f64::min);
        if low < reach + f64::from(CONTACT_DISTANCE_M) {
            on_floor = true;
        } else {
            on_object = true;
        }
    }
    (on_object, on_floor)
}

/// The impact subset of a window of `regime` for object `j` (`t - k, t -> t + k`), if it belongs
/// to one: a floor-contact window in which the object is off the floor (floor distance test) at
/// `t` or at `t + k` is a [`Regime::FloorImpact`] (it lands, bounces or lifts off); an
/// object-contact window in which it is not touching another object (distance test) at `t` or
/// at `t + k` is a [`Regime::ObjectImpact`]. Other regimes have no subset.
pub fn impact_subset(
    flags: &ContactFlags,
    regime: Regime,
    j: usize,
    t: usize,
    k: usize,
) -> Option<Regime> {
    let (touching, subset) = match regime {
        Regime::FloorContact => (&flags.floor, Regime::FloorImpact),
        Regime::ObjectContact => (&flags.object, Regime::ObjectImpact),
        _ => return None,
    };
    (!(touching[t][j] && touching[t + k][j])).then_some(subset)
}

/// Squared-error sums of one predictor for one (regime, step size).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ErrorSums {
    /// Object-windows pooled.
    pub count: u64,
    /// Sum of squared centre errors, m^2.
    pub translation_sq: f64,
    /// Sum of squared geodesic angles, deg^2.
    pub orientation_sq: f64,
}

impl ErrorSums {
    /// Adds one object-window.
    pub fn add(&mut self, translation_m: f64, orientation_deg: f64) {
        self.count += 1;
        self.translation_sq += translation_m * translation_m;
        self.orientation_sq += orientation_deg * orientation_deg;
    }

    /// Adds another pool.
    pub fn merge(&mut self, o: &ErrorSums) {
        self.count += o.count;
        self.translation_sq += o.translation_sq;
        self.orientation_sq += o.orientation_sq;
    }

    /// Translation RMSE, metres (`None` without samples).
    pub fn translation_rmse_m(&self) -> Option<f64> {
        (self.count > 0).then(|| (self.translation_sq / self.count as f64).sqrt())
    }

    /// Orientation RMSE, degrees (`None` without samples).
    pub fn orientation_rmse_deg(&self) -> Option<f64> {
        (self.count > 0).then(|| (self.orientation_sq / self.count as f64).sqrt())
    }
}

/// One-step error pools of one predictor: `[step size index][regime]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RegimeErrors {
    /// Step sizes, frames, in order.
    pub step_sizes: Vec<u32>,
    /// Pools, `[step size][Regime declaration order]`.
    pub sums: Vec<[ErrorSums; 6]>,
}

impl RegimeErrors {
    /// Empty pools for these step sizes.
    pub fn new(step_sizes: &[u32]) -> Self {
        RegimeErrors {
            step_sizes: step_sizes.to_vec(),
            sums: vec![[ErrorSums::default(); 6]; step_sizes.len()],
        }
    }

    /// Adds one object-window of step size index `ki` in `regime`.
    pub fn add(&mut self, ki: usize, regime: Regime, translation_m: f64, orientation_deg: f64) {
        self.sums[ki][regime.index()].add(translation_m, orientation_deg);
    }

    /// The pool of (step size index, regime).
    pub fn get(&self, ki: usize, regime: Regime) -> &ErrorSums {
        &self.sums[ki][regime.index()]
    }
}

/// The one-step windows of a scene of `frames` frames for step size `k`: the frames `t` with
/// `t >= k`, `t >= 1` and `t + k <= frames - 1`, every `stride`-th from the first.
pub fn windows(frames: usize, k: usize, stride: usize) -> Vec<usize> {
    let first = k.max(1);
    if k == 0 || frames < first + k + 1 {
        return Vec::new();
    }
    (first..=frames - 1 - k).step_by(stride.max(1)).collect()
}
