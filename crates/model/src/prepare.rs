//! Scene preparation: input validation and the per-object caches that stay fixed over a
//! rollout (anchors, encoder grouping, anchor-to-point distances).
//!
//! Farthest point sampling and nearest-neighbour grouping are invariant under rigid motion, so
//! they are computed once on the reference (body-frame) cloud. The FPS start point is the
//! point farthest from the cloud's centroid (ties broken by coordinates), which makes the
//! chosen sets independent of the order in which points are given.

use dynaserve_geometry::farthest_point_sampling;

use crate::api::{ObjectInput, Pose, SceneState};
use crate::config::PreparedKey;
use crate::{ModelConfig, ModelError};

/// Largest accepted absolute body-frame coordinate, metres.
pub const MAX_BODY_EXTENT: f32 = 1.0e3;
/// Largest accepted absolute world coordinate of a pose translation, metres.
pub const MAX_WORLD_EXTENT: f32 = 1.0e5;
/// Largest accepted step size in frames.
pub const MAX_DT_STEPS: u32 = 1024;

/// One object's validated input and caches.
#[derive(Clone, Debug)]
pub(crate) struct PreparedObject {
    /// Body-frame surface points `[n, 3]`, metres.
    pub reference: Vec<[f32; 3]>,
    /// `[ln(mass), friction, restitution]` (raw, not normalised).
    pub params: [f32; 3],
    /// Indices of the K anchors (farthest point sampling; repeats when n < K).
    pub anchors: Vec<usize>,
    /// Indices of the set-abstraction centres `[sa_centres]`.
    pub centres: Vec<usize>,
    /// Neighbour indices `[sa_centres * sa_neighbours]`, row-major per centre.
    pub neighbours: Vec<usize>,
    /// Squared anchor-to-point distances `[K, n]`, m^2 (rigid-invariant).
    pub anchor_d2: Vec<f32>,
    /// Centroid of the reference cloud, metres.
    pub centroid: [f32; 3],
    /// Inverse of the reference cloud's floored inertia per unit mass about its centroid,
    /// body frame, 1/m^2 ([`crate::rigidformer::inertia::floored_inertia_inverse`]; the contact
    /// wrench rotates it into the world each step).
    pub inertia_inv: nalgebra::Matrix3<f32>,
    /// Body-frame outward unit normals `[n, 3]` when the model reads surface normals
    /// ([`crate::DynamicsConfig::surface_normals`]); empty otherwise.
    pub normals: Vec<[f32; 3]>,
    /// Largest distance of a reference point from the body origin (the centre of mass),
    /// metres: the radius of a sphere about the centre holding the cloud in any attitude.
    pub radius: f32,
    /// The object is kinematic ([`ObjectInput::kinematic`](crate::ObjectInput::kinematic)):
    /// its motion is given from outside and need not be ballistic.
    pub kinematic: bool,
}

/// A validated scene with the per-object caches a model computes once (anchor indices by FPS on
/// the reference cloud, encoder grouping). Made by [`WorldModel::prepare`](crate::WorldModel::prepare)
/// and valid only for models with the same anchor and grouping sizes, or with those of one of
/// the further preparations an ensemble attaches (members of other sizes).
#[derive(Clone, Debug)]
pub struct PreparedScene {
    pub(crate) objects: Vec<PreparedObject>,
    /// Sizes of the model that prepared the scene.
    pub(crate) key: PreparedKey,
    /// Total number of points.
    pub(crate) total_points: usize,
    /// The same objects prepared for models of other anchor or grouping sizes (an ensemble's
    /// members, [`PreparedScene::attach`]); none of them has further preparations.
    pub(crate) others: Vec<PreparedScene>,
}

impl PreparedScene {
    /// The preparation of this scene for a model whose [`PreparedKey`] is `key`: this one or
    /// one attached to it, `None` when there is none.
    pub(crate) fn for_key(&self, key: PreparedKey) -> Option<&PreparedScene> {
        std::iter::once(self)
            .chain(&self.others)
            .find(|s| s.key == key)
    }

    /// Attaches `other`, the same objects prepared for a model of other anchor or grouping
    /// sizes, so that models of either size can step this scene. Refuses a preparation of
    /// another scene (other object count or reference clouds) and one whose sizes this scene
    /// already serves.
    pub(crate) fn attach(&mut self, mut other: PreparedScene) -> Result<(), ModelError> {
        let same_objects = other.objects.len() == self.objects.len()
            && other
                .objects
                .iter()
                .zip(&self.objects)
                .all(|(a, b)| a.reference == b.reference);
        if !same_objects {
            return Err(ModelError::Internal(
                "a preparation of another scene was attached".into(),
            ));
        }
        if self.for_key(other.key).is_some() {
            return Err(ModelError::Internal(format!(
                "the scene already has a preparation for {:?}",
                other.key
            )));
        }
        other.others.clear();
        self.others.push(other);
        Ok(())
    }

    /// Number of objects.
    pub fn len(&self) -> usize {
        self.objects.len()
    }

    /// True when the scene has no objects (never the case for a prepared scene).
    pub fn is_empty(&self) -> bool {
        self.objects.is_empty()
    }

    /// Total number of surface points over all objects.
    pub fn total_points(&self) -> usize {
        self.total_points
    }

    /// Number of points of object `j`, or `None` if out of range.
    pub fn points_of(&self, j: usize) -> Option<usize> {
        self.objects.get(j).map(|o| o.reference.len())
    }

    /// Body-frame reference cloud of object `j` (`[n, 3]`, metres).
    pub fn reference(&self, j: usize) -> Option<&[[f32; 3]]> {
        self.objects.get(j).map(|o| o.reference.as_slice())
    }

    /// Anchor indices of object `j` into its reference cloud (`[K]`).
    pub fn anchor_indices(&self, j: usize) -> Option<&[usize]> {
        self.objects.get(j).map(|o| o.anchors.as_slice())
    }

    /// How many distinct points of object `j` its encoder groups (the union of the
    /// `sa_centres` nearest-neighbour groups of `sa_neighbours` points each), or `None` if out
    /// of range. Only these points reach the object token through the set abstraction; every
    /// point still reaches the anchors through their distance-weighted pooling. At most
    /// `sa_centres * sa_neighbours`, so a cloud larger than that is never fully grouped.
    pub fn grouped_points(&self, j: usize) -> Option<usize> {
        self.objects.get(j).map(|o| {
            let mut seen = vec![false; o.reference.len()];
            o.neighbours
                .iter()
                .filter(|&&i| !std::mem::replace(&mut seen[i], true))
                .count()
        })
    }

    /// World-frame points of every object under `poses` (`X = R X_ref + p`), `[objects][n, 3]`.
    pub fn world_points(&self, poses: &[Pose]) -> Result<Vec<Vec<[f32; 3]>>, ModelError> {
        if poses.len() != self.objects.len() {
            return Err(ModelError::InvalidInput(format!(
                "expected {} poses, got {}",
                self.objects.len(),
                poses.len()
            )));
        }
        Ok(self
            .objects
            .iter()
            .zip(poses)
            .map(|(o, pose)| {
                o.reference
                    .iter()
                    .map(|x| pose.transform_point(*x))
                    .collect()
            })
            .collect())
    }

    /// Reorders the anchors of object `j` by `perm` (a permutation of `0..K`). Outputs must not
    /// change: this exists to test anchor-order invariance.
    pub fn permute_anchors(&mut self, j: usize, perm: &[usize]) -> Result<(), ModelError> {
        let o = self
            .objects
            .get_mut(j)
            .ok_or_else(|| ModelError::InvalidInput(format!("no object {j}")))?;
        let k = o.anchors.len();
        let mut seen = vec![false; k];
        if perm.len() != k
            || perm
                .iter()
                .any(|&i| i >= k || std::mem::replace(&mut seen[i], true))
        {
            return Err(ModelError::InvalidInput(format!(
                "anchor permutation must be a permutation of 0..{k}"
            )));
        }
        let n = o.reference.len();
        let anchors: Vec<usize> = perm.iter().map(|&i| o.anchors[i]).collect();
        let mut d2 = Vec::with_capacity(k * n);
        for &i in perm {
            d2.extend_from_slice(&o.anchor_d2[i * n..(i + 1) * n]);
        }
        o.anchors = anchors;
        o.anchor_d2 = d2;
        Ok(())
    }
}

fn finite3(p: &[f32; 3]) -> bool {
    p.iter().all(|v| v.is_finite())
}

/// The masses the network sees for a scene's objects, kilograms, in order: as given, or with
/// [`crate::DynamicsConfig::relative_mass`] the dynamic objects' multiplied by the one factor
/// that puts their mean `ln(mass / kg)` at the mass feature's normalisation mean, and every
/// [`ObjectInput::kinematic`] one's set to that mean (its mass moves nothing, so it is
/// neither a scale nor an input). Masses must be finite and > 0.
pub fn model_masses(cfg: &ModelConfig, objects: &[ObjectInput]) -> Vec<f32> {
    let given = objects.iter().map(|o| o.mass);
    if !cfg.dynamics.relative_mass || objects.is_empty() {
        return given.collect();
    }
    let reference = cfg
        .normalization
        .mean
        .get(crate::config::LN_MASS_FEATURE)
        .copied()
        .unwrap_or(0.0);
    // The dynamic objects' ratios to their geometric mean, placed at the reference; a
    // kinematic object (no ratio) at the reference itself.
    let scale = f64::from(reference).exp();
    let pairs: Vec<(f32, bool)> = objects.iter().map(|o| (o.mass, o.kinematic)).collect();
    crate::trained_ranges::mass_ratios(&pairs)
        .into_iter()
        .map(|r| (f64::from(r.unwrap_or(1.0)) * scale) as f32)
        .collect()
}

/// Validates a scene and builds its caches for a model with configuration `cfg`.
pub(crate) fn prepare_scene(
    cfg: &ModelConfig,
    objects: Vec<ObjectInput>,
) -> Result<PreparedScene, ModelError> {
    if objects.is_empty() {
        return Err(ModelError::InvalidInput("scene has no objects".into()));
    }
    if objects.len() > cfg.max_objects {
        return Err(ModelError::InvalidInput(format!(
            "scene has {} objects; this model accepts at most {}",
            objects.len(),
            cfg.max_objects
        )));
    }
    for (j, o) in objects.iter().enumerate() {
        let n = o.reference.len();
        if n == 0 {
            return Err(ModelError::InvalidInput(format!(
                "objects[{j}].reference is empty"
            )));
        }
        if n > cfg.max_points_per_object {
            return Err(ModelError::InvalidInput(format!(
                "objects[{j}].reference has {n} points; at most {} are accepted",
                cfg.max_points_per_object
            )));
        }
        if let Some(i) = o
            .reference
            .iter()
            .position(|p| !finite3(p) || p.iter().any(|v| v.abs() > MAX_BODY_EXTENT))
        {
            return Err(ModelError::InvalidInput(format!(
                "objects[{j}].reference[{i}] = {:?} is not finite or beyond {MAX_BODY_EXTENT} m",
                o.reference[i]
            )));
        }
        if !(o.mass.is_finite() && o.mass > 0.0) {
            return Err(ModelError::InvalidInput(format!(
                "objects[{j}].mass must be finite and > 0 kg, got {}",
                o.mass
            )));
        }
        if !(o.friction.is_finite() && o.friction >= 0.0) {
            return Err(ModelError::InvalidInput(format!(
                "objects[{j}].friction must be finite and >= 0, got {}",
                o.friction
            )));
        }
        if !(o.restitution.is_finite() && o.restitution >= 0.0) {
            return Err(ModelError::InvalidInput(format!(
                "objects[{j}].restitution must be finite and >= 0, got {}",
                o.restitution
            )));
        }
    }
    use rayon::prelude::*;
    let mut objects = objects;
    if cfg.dynamics.relative_mass {
        let masses = model_masses(cfg, &objects);
        for (o, m) in objects.iter_mut().zip(masses) {
            o.mass = m;
        }
    }
    let prepared: Result<Vec<PreparedObject>, ModelError> = objects
        .into_par_iter()
        .enumerate()
        .map(|(j, o)| {
            prepare_object(cfg, o)
                .map_err(|e| ModelError::InvalidInput(format!("objects[{j}]: {e}")))
        })
        .collect();
    let objects = prepared?;
    let total_points = objects.iter().map(|o| o.reference.len()).sum();
    Ok(PreparedScene {
        objects,
        key: cfg.prepared_key(),
        total_points,
        others: Vec::new(),
    })
}

fn d2(a: &[f32; 3], b: &[f32; 3]) -> f32 {
    let dx = a[0] - b[0];
    let dy = a[1] - b[1];
    let dz = a[2] - b[2];
    dx * dx + dy * dy + dz * dz
}

/// Order-independent start point: farthest from the centroid, ties by coordinates.
fn start_index(points: &[[f32; 3]], centroid: &[f32; 3]) -> usize {
    let mut best = 0;
    for i in 1..points.len() {
        let (di, db) = (d2(&points[i], centroid), d2(&points[best], centroid));
        let better = di > db
            || (di == db
                && points[i]
                    .partial_cmp(&points[best])
                    .is_some_and(|o| o == std::cmp::Ordering::Greater));
        if better {
            best = i;
        }
    }
    best
}

fn prepare_object(cfg: &ModelConfig, o: ObjectInput) -> Result<PreparedObject, String> {
    let n = o.reference.len();
    let mut c = [0f64; 3];
    for p in &o.reference {
        for d in 0..3 {
            c[d] += p[d] as f64;
        }
    }
    let centroid = [
        (c[0] / n as f64) as f32,
        (c[1] / n as f64) as f32,
        (c[2] / n as f64) as f32,
    ];
    let start = start_index(&o.reference, &centroid);
    let k = cfg.anchors.max(cfg.sa_centres);
    let order = farthest_point_sampling(&o.reference, k, start).map_err(|e| e.to_string())?;
    let anchors = order[..cfg.anchors].to_vec();
    let centres = order[..cfg.sa_centres].to_vec();
    // Nearest neighbours of every centre on the reference cloud (ties by coordinates, so the
    // chosen set does not depend on point order); clouds smaller than the group repeat.
    let kn = cfg.sa_neighbours;
    let mut neighbours = Vec::with_capacity(centres.len() * kn);
    let mut idx: Vec<usize> = (0..n).collect();
    for &ci in &centres {
        let cp = o.reference[ci];
        let key = |i: &usize| (d2(&o.reference[*i], &cp), o.reference[*i]);
        let cmp = |a: &usize, b: &usize| {
            let (da, pa) = key(a);
            let (db, pb) = key(b);
            da.total_cmp(&db)
                .then(pa[0].total_cmp(&pb[0]))
                .then(pa[1].total_cmp(&pb[1]))
                .then(pa[2].total_cmp(&pb[2]))
        };
        let take = kn.min(n);
        if take < n {
            idx.select_nth_unstable_by(take - 1, cmp);
        }
        let mut group = idx[..take].to_vec();
        group.sort_by(cmp);
        for r in 0..kn {
            neighbours.push(group[r % take]);
        }
    }
    let mut anchor_d2 = Vec::with_capacity(anchors.len() * n);
    for &a in &anchors {
        let ap = o.reference[a];
        anchor_d2.extend(o.reference.iter().map(|p| d2(p, &ap)));
    }
    let radius = o
        .reference
        .iter()
        .map(|p| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt())
        .fold(0.0f32, f32::max);
    let normals = if cfg.dynamics.reads_normals() {
        crate::rigidformer::features::body_normals(&o.reference)
    } else {
        Vec::new()
    };
    let inertia_inv = crate::rigidformer::inertia::floored_inertia_inverse(&o.reference, centroid);
    Ok(PreparedObject {
        params: crate::rigidformer::features::object_params(o.mass, o.friction, o.restitution),
        normals,
        radius,
        kinematic: o.kinematic,
        reference: o.reference,
        anchors,
        centres,
        neighbours,
        anchor_d2,
        inertia_inv,
        centroid,
    })
}

/// Validates a scene state against its prepared scene and normalises the quaternions
/// (`earlier` too, when given).
pub(crate) fn validate_state(
    scene: &PreparedScene,
    state: &SceneState,
    dt_steps: u32,
    what: &str,
) -> Result<SceneState, ModelError> {
    let m = scene.len();
    if state.current.len() != m || state.previous.len() != m {
        return Err(ModelError::InvalidInput(format!(
            "{what}: scene has {m} objects but the state has {} current and {} previous poses",
            state.current.len(),
            state.previous.len()
        )));
    }
    if let Some(earlier) = state.earlier.as_ref().filter(|e| e.len() != m) {
        return Err(ModelError::InvalidInput(format!(
            "{what}: scene has {m} objects but the state has {} earlier poses",
            earlier.len()
        )));
    }
    if dt_steps == 0 || dt_steps > MAX_DT_STEPS {
        return Err(ModelError::InvalidInput(format!(
            "{what}: dt_steps must be in 1..={MAX_DT_STEPS}, got {dt_steps}"
        )));
    }
    let norm = |list: &[Pose], name: &str| -> Result<Vec<Pose>, ModelError> {
        list.iter()
            .enumerate()
            .map(|(j, p)| {
                normalise_pose(p)
                    .map_err(|e| ModelError::InvalidInput(format!("{what}: {name}[{j}]: {e}")))
            })
            .collect()
    };
    Ok(SceneState {
        previous: norm(&state.previous, "previous")?,
        current: norm(&state.current, "current")?,
        earlier: match &state.earlier {
            Some(e) => Some(norm(e, "earlier")?),
            None => None,
        },
        carry: Default::default(),
    })
}

/// The model's domain check of one pose: a finite translation within [`MAX_WORLD_EXTENT`]
/// metres of the origin on every axis and a finite quaternion with squared norm at least
/// `1e-6`. Returns the pose with its quaternion normalised, or why it is outside the domain.
pub fn normalise_pose(p: &Pose) -> Result<Pose, String> {
    if !finite3(&p.translation) || p.translation.iter().any(|v| v.abs() > MAX_WORLD_EXTENT) {
        return Err(format!(
            "translation {:?} is not finite or beyond {MAX_WORLD_EXTENT} m",
            p.translation
        ));
    }
    let q = p.rotation;
    let n2: f32 = q.iter().map(|v| v * v).sum();
    if !n2.is_finite() || n2 < 1e-6 {
        return Err(format!("rotation {q:?} is not a usable quaternion"));
    }
    let n = n2.sqrt();
    Ok(Pose {
        translation: p.translation,
        rotation: [q[0] / n, q[1] / n, q[2] / n, q[3] / n],
    })
}
