//! Contact features: for every point of every object, the displacement to the nearest point of
//! any *other* object or to the ground plane, clipped at a contact radius.
//!
//! # Definition
//!
//! Objects are contiguous ranges of `points` (`[n, 3]`, metres, world frame) given by
//! `offsets` (`[objects + 1]`): object `i` owns `points[offsets[i]..offsets[i + 1]]`. With
//! `r = radius`, for a point `x` of object `i`:
//!
//! - the ground displacement is `g = (0, 0, ground_z - x_z)`; the ground is a candidate when
//!   `g_z^2 < r^2`;
//! - a point `y` of another object `j != i` is a candidate when `|y - x|^2 < r^2` and
//!   `|y - x|^2 < g_z^2` (a point beats the ground only when strictly nearer);
//! - the result is `y - x` for the nearest point candidate (ties: the smallest index into
//!   `points`), else `g` if the ground is a candidate, else `g` clipped to length `r`, i.e.
//!   `(0, 0, +-r)` pointing towards the ground plane; with no ground (`ground_z = None`) the
//!   fallback is the zero vector.
//!
//! Squared distances are computed in `f32` as `dx*dx + dy*dy + dz*dz` by both
//! [`contact_features`] and [`contact_features_brute_force`], so the two return bit-identical
//! results. Points with a non-finite coordinate are never candidates; their own result is the
//! fallback. A radius that is not finite and positive is treated as 0 (every result is then a
//! zero vector). Empty objects (`offsets[i] == offsets[i + 1]`) are allowed and produce no rows.
//!
//! # Algorithm of [`contact_features`]
//!
//! 1. Per-object axis-aligned bounding boxes; sort-and-sweep on x finds the pairs of objects
//!    whose boxes come within the radius of each other (the broad phase). For each object, the
//!    union of its neighbours' boxes, expanded by the radius, bounds where its points can have
//!    a candidate (its *interest box*).
//! 2. Only points inside their object's interest box enter that object's own dense uniform grid
//!    (cell edge slightly larger than the radius, coarsened for very sparse objects) and only
//!    those points search, in the grid of each near object whose reach holds them, the
//!    surrounding 3 x 3 x 3 cells, skipping cells that cannot beat the best distance so far.
//!    A point never visits its own object's points; every point outside its interest box gets
//!    its ground fallback directly.
//! 3. The per-point searches run on rayon's pool when the scene has at least
//!    [`PARALLEL_MIN_POINTS`] points; smaller scenes run serially.
//!
//! [`contact_hits`] runs the same search and also returns what each displacement reaches (the
//! nearest point's index, the ground, or nothing), for features that need the motion of the
//! contact surface.
//!
//! The cost is `O(n)` plus the work inside near pairs. Scratch buffers live in a per-thread
//! [`ContactWorkspace`], so repeated calls do not allocate except for the returned vector
//! (use [`contact_features_into`] to reuse that too).

use std::cell::RefCell;

use rayon::prelude::*;

use crate::{GeometryError, Point};

/// Scenes with at least this many points search in parallel on rayon's pool; smaller ones run
/// serially. Measured with the `contact/threshold` bench on a busy two-core machine, the
/// parallel search was slower at 4096 points (1.59 vs 1.47 ms) and no faster at 13824 and
/// 32768 points, so only very large scenes fan out (callers usually already run scenes in
/// parallel). Tune per deployment with [`ContactWorkspace::with_parallel_threshold`].
pub const PARALLEL_MIN_POINTS: usize = 32768;

/// Broad-phase and grid margin: boxes are expanded and cells sized by `radius * MARGIN`, so
/// that rounding can never hide a candidate the brute force would see.
const MARGIN: f32 = 1.05;

/// Maximum grid cells along one axis; the cell edge grows for very large scenes so that cell
/// coordinates stay exact enough in `f32`.
const MAX_CELLS_PER_AXIS: f32 = 65536.0;

/// Rows of the 3 x 3 x 3 neighbourhood as (dy, dz), the centre first so that the best
/// distance shrinks early and prunes more of the rest.
const ROW_ORDER: [(i64, i64); 9] = [
    (0, 0),
    (-1, 0),
    (1, 0),
    (0, -1),
    (0, 1),
    (-1, -1),
    (1, -1),
    (-1, 1),
    (1, 1),
];

/// Slack (in cells) subtracted from the distance bounds that prune cells: far larger than the
/// rounding of scaled coordinates (below 0.01 cells with at most `MAX_CELLS_PER_AXIS` cells per
/// axis), so a cell is skipped only when every point in it is strictly farther than the best.
const PRUNE_SLACK: f32 = 0.03;

/// Points handed to one rayon task.
const CHUNK: usize = 512;

/// Parameters of the contact features.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct ContactConfig {
    /// Contact radius in metres (finite, > 0): displacements are clipped to this length.
    pub radius: f32,
    /// Height of the ground plane's top (metres), or `None` for no ground.
    pub ground_z: Option<f32>,
}

impl Default for ContactConfig {
    /// Radius 0.25 m, ground at z = 0.
    fn default() -> Self {
        ContactConfig {
            radius: 0.25,
            ground_z: Some(0.0),
        }
    }
}

impl ContactConfig {
    /// Checks that the radius is finite and positive and the ground height finite.
    pub fn validate(&self) -> Result<(), GeometryError> {
        if !(self.radius.is_finite() && self.radius > 0.0) {
            return Err(GeometryError::Invalid(format!(
                "contact radius must be finite and > 0, got {}",
                self.radius
            )));
        }
        if let Some(z) = self.ground_z
            && !z.is_finite()
        {
            return Err(GeometryError::NonFinite("contact ground_z"));
        }
        Ok(())
    }

    fn effective_radius(&self) -> f32 {
        if self.radius.is_finite() && self.radius > 0.0 {
            self.radius
        } else {
            0.0
        }
    }
}

/// Checks that `offsets` (`[objects + 1]`) splits `n_points` points into contiguous objects:
/// starts at 0, never decreases, ends at `n_points`.
pub fn validate_offsets(n_points: usize, offsets: &[usize]) -> Result<(), GeometryError> {
    if offsets.is_empty() {
        return Err(GeometryError::Empty("object offsets"));
    }
    if offsets[0] != 0 {
        return Err(GeometryError::Invalid(format!(
            "object offsets must start at 0, got {}",
            offsets[0]
        )));
    }
    if offsets.windows(2).any(|w| w[1] < w[0]) {
        return Err(GeometryError::Invalid(
            "object offsets must not decrease".into(),
        ));
    }
    let last = offsets[offsets.len() - 1];
    if last != n_points {
        return Err(GeometryError::LengthMismatch {
            what: "points (object offsets end)",
            expected: last,
            got: n_points,
        });
    }
    if n_points > u32::MAX as usize || offsets.len() > u32::MAX as usize {
        return Err(GeometryError::Invalid(
            "too many points or objects for contact features".into(),
        ));
    }
    Ok(())
}

#[inline(always)]
fn dist2(a: &Point, b: &Point) -> f32 {
    let dx = b[0] - a[0];
    let dy = b[1] - a[1];
    let dz = b[2] - a[2];
    dx * dx + dy * dy + dz * dz
}

/// What a point's contact displacement points at (see [`contact_hits`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ContactSource {
    /// The nearest point of another object, by its index into `points`.
    Point(u32),
    /// The ground plane, within the radius and nearer than every other object's point.
    Ground,
    /// Nothing within the radius: the displacement is the clipped (or zero) fallback.
    Free,
}

/// One point's contact feature together with what it points at.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactHit {
    /// The contact displacement of [`contact_features`], metres, world frame.
    pub displacement: Point,
    /// The surface the displacement reaches.
    pub source: ContactSource,
}

impl ContactHit {
    #[inline(always)]
    fn new(displacement: Point, source: ContactSource) -> ContactHit {
        ContactHit {
            displacement,
            source,
        }
    }
}

/// The squared distance a point candidate must beat, the result when none does and what
/// that result points at.
#[inline(always)]
fn ground_fallback(x: &Point, r: f32, ground_z: Option<f32>) -> (f32, Point, ContactSource) {
    let r2 = r * r;
    match ground_z {
        None => (r2, [0.0; 3], ContactSource::Free),
        Some(gz) => {
            let g = gz - x[2];
            let g2 = g * g;
            if g2 < r2 {
                (g2, [0.0, 0.0, g], ContactSource::Ground)
            } else {
                (r2, [0.0, 0.0, r.copysign(g)], ContactSource::Free)
            }
        }
    }
}

/// Reference implementation of [`contact_features`] by exhaustive search, `O(n^2)`; same
/// definition and bit-identical results (see the module docs). For tests and benchmarks.
///
/// # Panics
/// If `offsets` is malformed (see [`validate_offsets`]).
pub fn contact_features_brute_force(
    points: &[Point],
    offsets: &[usize],
    cfg: &ContactConfig,
) -> Vec<Point> {
    contact_hits_brute_force(points, offsets, cfg)
        .into_iter()
        .map(|h| h.displacement)
        .collect()
}

/// Reference implementation of [`contact_hits`] by exhaustive search, `O(n^2)`; bit-identical
/// displacements and the same sources. For tests and benchmarks.
///
/// # Panics
/// If `offsets` is malformed (see [`validate_offsets`]).
pub fn contact_hits_brute_force(
    points: &[Point],
    offsets: &[usize],
    cfg: &ContactConfig,
) -> Vec<ContactHit> {
    if let Err(e) = validate_offsets(points.len(), offsets) {
        panic!("contact_features_brute_force: {e}");
    }
    let r = cfg.effective_radius();
    let mut out = Vec::with_capacity(points.len());
    for i in 0..offsets.len() - 1 {
        for x in &points[offsets[i]..offsets[i + 1]] {
            let (mut best_d2, fallback, kind) = ground_fallback(x, r, cfg.ground_z);
            let mut best = None;
            for j in 0..offsets.len() - 1 {
                if j == i {
                    continue;
                }
                for (k, y) in points
                    .iter()
                    .enumerate()
                    .take(offsets[j + 1])
                    .skip(offsets[j])
                {
                    let d2 = dist2(x, y);
                    if d2 < best_d2 {
                        best_d2 = d2;
                        best = Some((y, k));
                    }
                }
            }
            out.push(match best {
                Some((y, k)) => ContactHit::new(
                    [y[0] - x[0], y[1] - x[1], y[2] - x[2]],
                    ContactSource::Point(k as u32),
                ),
                None => ContactHit::new(fallback, kind),
            });
        }
    }
    out
}

/// Contact features of a multi-object scene (see the module docs for the exact definition
/// and the algorithm). `points`: `[n, 3]` metres; `offsets`: `[objects + 1]`; returns
/// `[n, 3]` displacements in metres, world frame, each no longer than the radius.
///
/// # Panics
/// If `offsets` is malformed (see [`validate_offsets`]); callers handling untrusted input
/// validate first.
pub fn contact_features(points: &[Point], offsets: &[usize], cfg: &ContactConfig) -> Vec<Point> {
    let mut out = Vec::new();
    contact_features_into(points, offsets, cfg, &mut out);
    out
}

/// [`contact_features`] writing into `out` (cleared and resized to `[n, 3]`), so a caller in
/// a loop reuses its allocation. Uses this thread's [`ContactWorkspace`].
///
/// # Panics
/// If `offsets` is malformed (see [`validate_offsets`]).
pub fn contact_features_into(
    points: &[Point],
    offsets: &[usize],
    cfg: &ContactConfig,
    out: &mut Vec<Point>,
) {
    with_workspace(|ws| ws.compute(points, offsets, cfg, out));
}

/// [`contact_features`] that also says what every displacement points at: the index of the
/// nearest point of another object, the ground, or nothing within the radius. Same search,
/// bit-identical displacements. `points`: `[n, 3]` metres; `offsets`: `[objects + 1]`;
/// returns `[n]` hits.
///
/// # Panics
/// If `offsets` is malformed (see [`validate_offsets`]).
pub fn contact_hits(points: &[Point], offsets: &[usize], cfg: &ContactConfig) -> Vec<ContactHit> {
    let mut out = Vec::new();
    with_workspace(|ws| ws.compute_hits(points, offsets, cfg, &mut out));
    out
}

/// Runs `f` on this thread's [`ContactWorkspace`].
fn with_workspace(f: impl FnOnce(&mut ContactWorkspace)) {
    thread_local! {
        static WORKSPACE: RefCell<ContactWorkspace> = RefCell::new(ContactWorkspace::default());
    }
    WORKSPACE.with(|ws| match ws.try_borrow_mut() {
        Ok(mut ws) => f(&mut ws),
        // Re-entered from inside a computation on this thread (only possible through rayon
        // work stealing): use a fresh workspace.
        Err(_) => f(&mut ContactWorkspace::default()),
    });
}

#[derive(Clone, Copy, Debug)]
struct Aabb {
    lo: [f32; 3],
    hi: [f32; 3],
}

impl Aabb {
    const EMPTY: Aabb = Aabb {
        lo: [f32::INFINITY; 3],
        hi: [f32::NEG_INFINITY; 3],
    };

    fn is_empty(&self) -> bool {
        self.lo[0] > self.hi[0]
    }

    #[inline(always)]
    fn grow_point(&mut self, p: &Point) {
        for (d, v) in p.iter().enumerate() {
            self.lo[d] = self.lo[d].min(*v);
            self.hi[d] = self.hi[d].max(*v);
        }
    }

    fn grow_box(&mut self, b: &Aabb, pad: f32) {
        for d in 0..3 {
            self.lo[d] = self.lo[d].min(b.lo[d] - pad);
            self.hi[d] = self.hi[d].max(b.hi[d] + pad);
        }
    }

    /// False for NaN coordinates.
    #[inline(always)]
    fn contains(&self, p: &Point) -> bool {
        (0..3).all(|d| p[d] >= self.lo[d] && p[d] <= self.hi[d])
    }
}

/// One point in a grid: its coordinates and its index into `points`.
#[derive(Clone, Copy, Debug)]
struct Entry {
    p: Point,
    index: u32,
}

/// The dense uniform grid over one object's searchable points. Cells are indexed
/// `base + (z * ny + y) * nx + x`, so a row of three cells is one contiguous range of the
/// shared entry array.
#[derive(Clone, Copy, Debug)]
struct ObjectGrid {
    origin: [f32; 3],
    inv_cell: f32,
    dims: [i64; 3],
    base: usize,
    /// The grid's points' box expanded by the search margin: no point outside it can have a
    /// candidate in this grid.
    reach: Aabb,
}

/// `floor(v)` for the cell coordinate range used here (`|v|` far below `2^63`); saturates.
#[inline(always)]
fn floor_i64(v: f32) -> i64 {
    let t = v as i64;
    if (t as f32) > v { t - 1 } else { t }
}

impl ObjectGrid {
    /// Cell index of one of the grid's own points (always inside the grid: its scaled offsets
    /// are `>= 0`, so truncation is the floor; clamped for safety).
    #[inline(always)]
    fn bucket_of(&self, p: &Point) -> usize {
        let c = |d: usize| {
            (((p[d] - self.origin[d]) * self.inv_cell) as i64).clamp(0, self.dims[d] - 1)
        };
        self.base + ((c(2) * self.dims[1] + c(1)) * self.dims[0] + c(0)) as usize
    }
}

/// Reusable scratch memory for [`contact_features`]. One lives in each thread that calls the
/// free functions; hold your own to control where the memory lives. It keeps the capacity of
/// the largest scene seen.
#[derive(Debug)]
pub struct ContactWorkspace {
    parallel_min_points: usize,
    object_of: Vec<u32>,
    boxes: Vec<Aabb>,
    interest: Vec<Aabb>,
    order: Vec<u32>,
    pairs: Vec<[u32; 2]>,
    neighbour_start: Vec<u32>,
    /// Per neighbour: its grid's reach and its index, stored together so the reach tests of
    /// a query read memory in order.
    neighbours: Vec<(Aabb, u32)>,
    grids: Vec<ObjectGrid>,
    inserted: Vec<u32>,
    buckets: Vec<u32>,
    cell_start: Vec<u32>,
    entries: Vec<Entry>,
}

impl Default for ContactWorkspace {
    /// An empty workspace with the [`PARALLEL_MIN_POINTS`] threshold.
    fn default() -> Self {
        ContactWorkspace::with_parallel_threshold(PARALLEL_MIN_POINTS)
    }
}

impl ContactWorkspace {
    /// An empty workspace that searches in parallel for scenes of at least `min_points` points
    /// (0: always, `usize::MAX`: never). Running inside a one-thread rayon pool is serial too.
    pub fn with_parallel_threshold(min_points: usize) -> Self {
        ContactWorkspace {
            parallel_min_points: min_points,
            object_of: Vec::new(),
            boxes: Vec::new(),
            interest: Vec::new(),
            order: Vec::new(),
            pairs: Vec::new(),
            neighbour_start: Vec::new(),
            neighbours: Vec::new(),
            grids: Vec::new(),
            inserted: Vec::new(),
            buckets: Vec::new(),
            cell_start: Vec::new(),
            entries: Vec::new(),
        }
    }

    /// Computes the contact features of one scene into `out` (see [`contact_features`]).
    ///
    /// # Panics
    /// If `offsets` is malformed (see [`validate_offsets`]).
    pub fn compute(
        &mut self,
        points: &[Point],
        offsets: &[usize],
        cfg: &ContactConfig,
        out: &mut Vec<Point>,
    ) {
        self.search(points, offsets, cfg, out, |d, _| d);
    }

    /// Computes the contact hits of one scene into `out` (see [`contact_hits`]).
    ///
    /// # Panics
    /// If `offsets` is malformed (see [`validate_offsets`]).
    pub fn compute_hits(
        &mut self,
        points: &[Point],
        offsets: &[usize],
        cfg: &ContactConfig,
        out: &mut Vec<ContactHit>,
    ) {
        self.search(points, offsets, cfg, out, ContactHit::new);
    }

    /// The search behind [`ContactWorkspace::compute`] and [`ContactWorkspace::compute_hits`]:
    /// `emit` turns a displacement and its source into one output row (monomorphised, so the
    /// displacement-only path carries no source).
    fn search<T, F>(
        &mut self,
        points: &[Point],
        offsets: &[usize],
        cfg: &ContactConfig,
        out: &mut Vec<T>,
        emit: F,
    ) where
        T: Copy + Send,
        F: Fn(Point, ContactSource) -> T + Sync,
    {
        if let Err(e) = validate_offsets(points.len(), offsets) {
            panic!("contact_features: {e}");
        }
        let n = points.len();
        let objects = offsets.len() - 1;
        let r = cfg.effective_radius();
        let ground_z = cfg.ground_z;
        out.clear();
        out.resize(n, emit([0.0; 3], ContactSource::Free));
        if n == 0 {
            return;
        }

        // Per-object boxes over finite points, and the object of every point.
        self.object_of.clear();
        self.boxes.clear();
        for i in 0..objects {
            let mut b = Aabb::EMPTY;
            for p in &points[offsets[i]..offsets[i + 1]] {
                if p.iter().all(|v| v.is_finite()) {
                    b.grow_point(p);
                }
            }
            self.boxes.push(b);
            self.object_of
                .extend(std::iter::repeat_n(i as u32, offsets[i + 1] - offsets[i]));
        }

        // Broad phase: sort-and-sweep on x. Every near pair widens both interest boxes.
        let pad = r * MARGIN;
        self.interest.clear();
        self.interest.resize(objects, Aabb::EMPTY);
        self.pairs.clear();
        self.order.clear();
        self.order
            .extend((0..objects as u32).filter(|&i| !self.boxes[i as usize].is_empty()));
        let boxes = &self.boxes;
        self.order
            .sort_unstable_by(|&a, &b| boxes[a as usize].lo[0].total_cmp(&boxes[b as usize].lo[0]));
        if r > 0.0 {
            for (s, &a) in self.order.iter().enumerate() {
                let ba = self.boxes[a as usize];
                for &b in &self.order[s + 1..] {
                    let bb = self.boxes[b as usize];
                    if bb.lo[0] > ba.hi[0] + pad {
                        break;
                    }
                    let near =
                        (1..3).all(|d| bb.lo[d] <= ba.hi[d] + pad && ba.lo[d] <= bb.hi[d] + pad);
                    if near {
                        self.pairs.push([a, b]);
                        self.interest[a as usize].grow_box(&bb, pad);
                        self.interest[b as usize].grow_box(&ba, pad);
                    }
                }
            }
        }
        if self.pairs.is_empty() {
            for (x, o) in points.iter().zip(out.iter_mut()) {
                let (_, d, source) = ground_fallback(x, r, ground_z);
                *o = emit(d, source);
            }
            return;
        }

        // Per object, the points inside its interest box (the only ones that can be, or have,
        // a candidate) go into the object's own dense grid; cell edge >= radius * MARGIN, grown
        // when needed so that a grid has at most 4 cells per point + 64 and at most
        // MAX_CELLS_PER_AXIS cells along an axis.
        self.inserted.clear();
        self.grids.clear();
        let mut total_cells = 0usize;
        for i in 0..objects {
            let first = self.inserted.len();
            let interest = self.interest[i];
            let mut span = Aabb::EMPTY;
            for (idx, p) in points
                .iter()
                .enumerate()
                .take(offsets[i + 1])
                .skip(offsets[i])
            {
                if interest.contains(p) {
                    self.inserted.push(idx as u32);
                    span.grow_point(p);
                }
            }
            let count = self.inserted.len() - first;
            if count == 0 {
                self.grids.push(ObjectGrid {
                    origin: [0.0; 3],
                    inv_cell: 0.0,
                    dims: [0; 3],
                    base: total_cells,
                    reach: Aabb::EMPTY,
                });
                continue;
            }
            let extent = [0, 1, 2].map(|d| span.hi[d] - span.lo[d]);
            let max_extent = extent.iter().copied().fold(0.0f32, f32::max);
            let limit = 4 * count as i64 + 64;
            let mut cell = pad.max(max_extent / MAX_CELLS_PER_AXIS);
            let dims = loop {
                let dims = extent.map(|e| (e / cell) as i64 + 1);
                if dims[0] * dims[1] * dims[2] <= limit {
                    break dims;
                }
                cell *= 1.5;
            };
            let mut reach = Aabb::EMPTY;
            reach.grow_box(&span, pad);
            self.grids.push(ObjectGrid {
                origin: span.lo,
                inv_cell: 1.0 / cell,
                dims,
                base: total_cells,
                reach,
            });
            total_cells += (dims[0] * dims[1] * dims[2]) as usize;
        }

        // Neighbour lists (CSR) of objects with a non-empty grid.
        self.neighbour_start.clear();
        self.neighbour_start.resize(objects + 1, 0);
        let has_grid = |grids: &[ObjectGrid], j: u32| grids[j as usize].dims[0] > 0;
        for &[a, b] in &self.pairs {
            if has_grid(&self.grids, b) {
                self.neighbour_start[a as usize + 1] += 1;
            }
            if has_grid(&self.grids, a) {
                self.neighbour_start[b as usize + 1] += 1;
            }
        }
        for i in 0..objects {
            self.neighbour_start[i + 1] += self.neighbour_start[i];
        }
        self.neighbours.clear();
        self.neighbours
            .resize(self.neighbour_start[objects] as usize, (Aabb::EMPTY, 0));
        self.order.clear();
        self.order
            .extend_from_slice(&self.neighbour_start[..objects]);
        for &[a, b] in &self.pairs {
            if has_grid(&self.grids, b) {
                self.neighbours[self.order[a as usize] as usize] =
                    (self.grids[b as usize].reach, b);
                self.order[a as usize] += 1;
            }
            if has_grid(&self.grids, a) {
                self.neighbours[self.order[b as usize] as usize] =
                    (self.grids[a as usize].reach, a);
                self.order[b as usize] += 1;
            }
        }

        // Counting sort of the inserted points into their grids' cells.
        self.cell_start.clear();
        self.cell_start.resize(total_cells + 1, 0);
        self.buckets.clear();
        for &idx in &self.inserted {
            let g = &self.grids[self.object_of[idx as usize] as usize];
            let b = g.bucket_of(&points[idx as usize]);
            self.buckets.push(b as u32);
            self.cell_start[b + 1] += 1;
        }
        for b in 0..total_cells {
            self.cell_start[b + 1] += self.cell_start[b];
        }
        self.entries.clear();
        self.entries.resize(
            self.inserted.len(),
            Entry {
                p: [0.0; 3],
                index: 0,
            },
        );
        // `order` becomes the per-cell write cursor (reused scratch).
        self.order.clear();
        self.order
            .extend_from_slice(&self.cell_start[..total_cells]);
        for (&idx, &b) in self.inserted.iter().zip(&self.buckets) {
            let slot = self.order[b as usize] as usize;
            self.order[b as usize] += 1;
            self.entries[slot] = Entry {
                p: points[idx as usize],
                index: idx,
            };
        }

        let interest = &self.interest;
        let object_of = &self.object_of;
        let grids = &self.grids;
        let neighbour_start = &self.neighbour_start;
        let neighbours = &self.neighbours;
        let cell_start = &self.cell_start;
        let entries = &self.entries;
        let query = |idx: usize, o: &mut T| {
            let x = &points[idx];
            let (limit2, fallback, kind) = ground_fallback(x, r, ground_z);
            let obj = object_of[idx] as usize;
            if !interest[obj].contains(x) {
                *o = emit(fallback, kind);
                return;
            }
            let mut best_d2 = limit2;
            let mut best_index = 0u32;
            let mut best: Option<Point> = None;
            let near =
                &neighbours[neighbour_start[obj] as usize..neighbour_start[obj + 1] as usize];
            for (reach, j) in near {
                if !reach.contains(x) {
                    continue;
                }
                let g = &grids[*j as usize];
                // Scaled position: whole part = cell, fraction = place inside the cell.
                let fx = (x[0] - g.origin[0]) * g.inv_cell;
                let fy = (x[1] - g.origin[1]) * g.inv_cell;
                let fz = (x[2] - g.origin[2]) * g.inv_cell;
                let c = [floor_i64(fx), floor_i64(fy), floor_i64(fz)];
                let frac = [fx - c[0] as f32, fy - c[1] as f32, fz - c[2] as f32];
                let cell2 = 1.0 / (g.inv_cell * g.inv_cell);
                // Lower bounds (cell units, squared) on the distance to the neighbouring cell
                // below and above along each axis, shrunk by a slack that covers rounding.
                let below = |d: usize| {
                    let v = (frac[d] - PRUNE_SLACK).max(0.0);
                    v * v
                };
                let above = |d: usize| {
                    let v = (1.0 - frac[d] - PRUNE_SLACK).max(0.0);
                    v * v
                };
                let gap = |d: usize, off: i64| match off {
                    -1 => below(d),
                    1 => above(d),
                    _ => 0.0,
                };
                for (dy, dz) in ROW_ORDER {
                    let (y, z) = (c[1] + dy, c[2] + dz);
                    if y < 0 || z < 0 || y >= g.dims[1] || z >= g.dims[2] {
                        continue;
                    }
                    let row_gap = gap(1, dy) + gap(2, dz);
                    if cell2 * row_gap > best_d2 {
                        continue;
                    }
                    let mut x0 = c[0] - 1;
                    if cell2 * (row_gap + gap(0, -1)) > best_d2 {
                        x0 = c[0];
                    }
                    let mut x1 = c[0] + 1;
                    if cell2 * (row_gap + gap(0, 1)) > best_d2 {
                        x1 = c[0];
                    }
                    let (x0, x1) = (x0.max(0), x1.min(g.dims[0] - 1));
                    if x0 > x1 {
                        continue;
                    }
                    let row = g.base + ((z * g.dims[1] + y) * g.dims[0]) as usize;
                    let a = cell_start[row + x0 as usize] as usize;
                    let e = cell_start[row + x1 as usize + 1] as usize;
                    for en in &entries[a..e] {
                        let d2 = dist2(x, &en.p);
                        if d2 < best_d2 || (d2 == best_d2 && en.index < best_index) {
                            best_d2 = d2;
                            best_index = en.index;
                            best = Some(en.p);
                        }
                    }
                }
            }
            *o = match best {
                Some(y) => emit(
                    [y[0] - x[0], y[1] - x[1], y[2] - x[2]],
                    ContactSource::Point(best_index),
                ),
                None => emit(fallback, kind),
            };
        };

        if n >= self.parallel_min_points && rayon::current_num_threads() > 1 {
            out.par_chunks_mut(CHUNK)
                .enumerate()
                .for_each(|(c, chunk)| {
                    for (k, o) in chunk.iter_mut().enumerate() {
                        query(c * CHUNK + k, o);
                    }
                });
        } else {
            for (idx, o) in out.iter_mut().enumerate() {
                query(idx, o);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn assert_bit_identical(fast: &[Point], brute: &[Point], what: &str) {
        assert_eq!(fast.len(), brute.len(), "{what}: length");
        for (k, (a, b)) in fast.iter().zip(brute).enumerate() {
            let same = (0..3).all(|d| a[d].to_bits() == b[d].to_bits());
            assert!(same, "{what}: point {k}: fast {a:?} vs brute force {b:?}");
        }
    }

    /// Random objects: blobs of points around random centres; some scenes are crowded so that
    /// objects touch and overlap, some objects sit below or straddle the ground.
    fn random_scene(rng: &mut ChaCha8Rng) -> (Vec<Point>, Vec<usize>) {
        let objects = rng.random_range(1..12);
        let area = rng.random_range(0.5..6.0f32);
        let mut points = Vec::new();
        let mut offsets = vec![0];
        for _ in 0..objects {
            let c = [
                rng.random_range(-area..area),
                rng.random_range(-area..area),
                rng.random_range(-0.6..2.0f32),
            ];
            let size = rng.random_range(0.05..0.8f32);
            let n = rng.random_range(1..80);
            for _ in 0..n {
                points.push([
                    c[0] + rng.random_range(-size..size),
                    c[1] + rng.random_range(-size..size),
                    c[2] + rng.random_range(-size..size),
                ]);
            }
            offsets.push(points.len());
        }
        (points, offsets)
    }

    #[test]
    fn equals_brute_force_on_random_scenes() {
        let mut rng = ChaCha8Rng::seed_from_u64(42);
        let configs = [
            ContactConfig::default(),
            ContactConfig {
                radius: 0.5,
                ground_z: None,
            },
            ContactConfig {
                radius: 0.1,
                ground_z: Some(0.3),
            },
        ];
        for s in 0..300 {
            let (points, offsets) = random_scene(&mut rng);
            for cfg in &configs {
                let fast = contact_features(&points, &offsets, cfg);
                let brute = contact_features_brute_force(&points, &offsets, cfg);
                assert_bit_identical(&fast, &brute, &format!("scene {s}, {cfg:?}"));
                // Every displacement is within the radius.
                for v in &fast {
                    let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                    assert!(len <= cfg.radius * 1.0001, "{v:?}");
                }
            }
        }
    }

    #[test]
    fn distant_groups_in_one_scene_still_match() {
        // Two copies of a crowded scene 300 m apart.
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for s in 0..40 {
            let (mut points, mut offsets) = random_scene(&mut rng);
            let n = points.len();
            let copy: Vec<Point> = points
                .iter()
                .map(|p| [p[0] + 300.0, p[1] - 200.0, p[2] + 100.0])
                .collect();
            points.extend(copy);
            let more: Vec<usize> = offsets[1..].iter().map(|o| o + n).collect();
            offsets.extend(more);
            let cfg = ContactConfig::default();
            assert_bit_identical(
                &contact_features(&points, &offsets, &cfg),
                &contact_features_brute_force(&points, &offsets, &cfg),
                &format!("sparse scene {s}"),
            );
        }
    }

    #[test]
    fn sparse_large_object_grows_its_cells_and_still_matches() {
        // A 40 m x 40 m sheet of 400 points would need 150 x 150 cells of the radius; its grid
        // coarsens instead. Small blobs lie on it and below it.
        let mut rng = ChaCha8Rng::seed_from_u64(17);
        let mut points: Vec<Point> = (0..400)
            .map(|_| {
                [
                    rng.random_range(-20.0..20.0f32),
                    rng.random_range(-20.0..20.0f32),
                    0.1,
                ]
            })
            .collect();
        let mut offsets = vec![0, points.len()];
        for _ in 0..30 {
            let c = [
                rng.random_range(-20.0..20.0f32),
                rng.random_range(-20.0..20.0f32),
                rng.random_range(-0.1..0.4f32),
            ];
            for _ in 0..20 {
                points.push([
                    c[0] + rng.random_range(-0.3..0.3f32),
                    c[1] + rng.random_range(-0.3..0.3f32),
                    c[2] + rng.random_range(-0.1..0.1f32),
                ]);
            }
            offsets.push(points.len());
        }
        for cfg in [
            ContactConfig::default(),
            ContactConfig {
                radius: 2.0,
                ground_z: None,
            },
        ] {
            assert_bit_identical(
                &contact_features(&points, &offsets, &cfg),
                &contact_features_brute_force(&points, &offsets, &cfg),
                "sheet",
            );
        }
    }

    #[test]
    fn equals_brute_force_on_large_scene_in_parallel() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut points = Vec::new();
        let mut offsets = vec![0];
        for i in 0..6 {
            for j in 0..6 {
                for _ in 0..150 {
                    points.push([
                        i as f32 + rng.random_range(-0.5..0.5f32),
                        j as f32 + rng.random_range(-0.5..0.5f32),
                        rng.random_range(0.0..1.0f32),
                    ]);
                }
                offsets.push(points.len());
            }
        }
        let cfg = ContactConfig::default();
        let brute = contact_features_brute_force(&points, &offsets, &cfg);
        // The default threshold (serial here), and the rayon path forced on, in a two-thread
        // pool so that it really splits even on a one-core machine.
        assert_bit_identical(
            &contact_features(&points, &offsets, &cfg),
            &brute,
            "grid of touching blobs",
        );
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        let mut ws = ContactWorkspace::with_parallel_threshold(0);
        let mut out = Vec::new();
        pool.install(|| ws.compute(&points, &offsets, &cfg, &mut out));
        assert_bit_identical(&out, &brute, "grid of touching blobs, parallel");
        // The workspace is reused without leftovers from the previous scene.
        pool.install(|| ws.compute(&points[..300], &[0, 150, 300], &cfg, &mut out));
        assert_bit_identical(
            &out,
            &contact_features_brute_force(&points[..300], &[0, 150, 300], &cfg),
            "reused workspace",
        );
    }

    #[test]
    fn touching_cubes_and_ties() {
        // Two lattices 0.1 m apart along x, on a 0.1 m lattice: many exactly tied distances.
        let mut points = Vec::new();
        for i in 0..4 {
            for j in 0..4 {
                points.push([0.0, i as f32 * 0.1, j as f32 * 0.1 + 0.5]);
            }
        }
        let split = points.len();
        for i in 0..4 {
            for j in 0..4 {
                points.push([0.1, i as f32 * 0.1, j as f32 * 0.1 + 0.5]);
            }
        }
        let offsets = vec![0, split, points.len()];
        let cfg = ContactConfig::default();
        let fast = contact_features(&points, &offsets, &cfg);
        assert_bit_identical(
            &fast,
            &contact_features_brute_force(&points, &offsets, &cfg),
            "lattice",
        );
        for (k, v) in fast.iter().enumerate() {
            let expect = if k < split { 0.1f32 } else { -0.1 };
            assert!((v[0] - expect).abs() < 1e-6 && v[1] == 0.0 && v[2] == 0.0);
        }
    }

    #[test]
    fn exact_ties_pick_the_smallest_index() {
        // The query point sits exactly between two points of other objects; whatever order the
        // grid visits them in, the smaller index into `points` wins, as in the brute force.
        let cfg = ContactConfig::default();
        let points = vec![[0.1, 0.0, 1.0], [-0.1, 0.0, 1.0], [0.0, 0.0, 1.0]];
        for offsets in [vec![0, 1, 2, 3], vec![0, 2, 3]] {
            let got = contact_features(&points, &offsets, &cfg);
            assert_eq!(got[2], [0.1, 0.0, 0.0]);
            assert_bit_identical(
                &got,
                &contact_features_brute_force(&points, &offsets, &cfg),
                "tie",
            );
        }
        // A point exactly as near as the ground loses to the ground.
        let points = vec![[0.0, 0.0, 0.125], [0.125, 0.0, 0.125]];
        let got = contact_features(&points, &[0, 1, 2], &cfg);
        assert_eq!(got[0], [0.0, 0.0, -0.125]);
    }

    /// The variant that names its source finds the same displacements as the plain search
    /// and the same sources as the brute force, including for non-finite and empty inputs.
    #[test]
    fn hits_equal_brute_force_and_plain_features() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let configs = [
            ContactConfig::default(),
            ContactConfig {
                radius: 0.5,
                ground_z: None,
            },
        ];
        let mut seen = [0usize; 3];
        for s in 0..150 {
            let (mut points, offsets) = random_scene(&mut rng);
            if s % 10 == 0 && !points.is_empty() {
                points[0] = [f32::NAN, 0.0, 0.0];
            }
            for cfg in &configs {
                let hits = contact_hits(&points, &offsets, cfg);
                let brute = contact_hits_brute_force(&points, &offsets, cfg);
                let plain = contact_features(&points, &offsets, cfg);
                let disp: Vec<Point> = hits.iter().map(|h| h.displacement).collect();
                assert_bit_identical(&disp, &plain, &format!("scene {s}, {cfg:?}"));
                for (k, (h, b)) in hits.iter().zip(&brute).enumerate() {
                    assert_eq!(h.source, b.source, "scene {s}, point {k}, {cfg:?}");
                    match h.source {
                        ContactSource::Point(j) => {
                            let y = points[j as usize];
                            let x = points[k];
                            let d = [y[0] - x[0], y[1] - x[1], y[2] - x[2]];
                            assert_eq!(d, h.displacement);
                            seen[0] += 1;
                        }
                        ContactSource::Ground => seen[1] += 1,
                        ContactSource::Free => seen[2] += 1,
                    }
                }
            }
        }
        assert!(
            seen.iter().all(|&c| c > 100),
            "every source occurs: {seen:?}"
        );
    }

    #[test]
    fn hits_name_the_ground_the_point_and_nothing() {
        let cfg = ContactConfig::default();
        // Object 0: one point high up, one near the ground; object 1: a point 0.05 m beside
        // the high one.
        let points = vec![[0.0, 0.0, 2.0], [3.0, 0.0, 0.1], [0.05, 0.0, 2.0]];
        let hits = contact_hits(&points, &[0, 2, 3], &cfg);
        assert_eq!(hits[0].source, ContactSource::Point(2));
        assert_eq!(hits[1].source, ContactSource::Ground);
        assert_eq!(hits[1].displacement, [0.0, 0.0, -0.1]);
        assert_eq!(hits[2].source, ContactSource::Point(0));
        let alone = contact_hits(&points[..1], &[0, 1], &cfg);
        assert_eq!(alone[0].source, ContactSource::Free);
        assert_eq!(alone[0].displacement, [0.0, 0.0, -0.25]);
    }

    #[test]
    fn ground_and_clipping() {
        let cfg = ContactConfig::default();
        // One object: high above, near, exactly on and below the ground.
        let points = vec![
            [0.0, 0.0, 3.0],
            [0.0, 0.0, 0.1],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, -0.5],
        ];
        let offsets = vec![0, points.len()];
        let got = contact_features(&points, &offsets, &cfg);
        assert_eq!(got[0], [0.0, 0.0, -0.25]);
        assert_eq!(got[1], [0.0, 0.0, -0.1]);
        assert_eq!(got[2], [0.0, 0.0, 0.0]);
        assert_eq!(got[3], [0.0, 0.0, 0.25]);
        // No ground: a lone object has no candidates at all.
        let none = ContactConfig {
            ground_z: None,
            ..cfg
        };
        assert!(
            contact_features(&points, &offsets, &none)
                .iter()
                .all(|v| *v == [0.0; 3])
        );
    }

    #[test]
    fn nearer_object_beats_ground_and_own_points_are_ignored() {
        let cfg = ContactConfig::default();
        // Object 0 at z = 0.2 (ground 0.2 away); object 1 just 0.05 m to its side.
        let points = vec![[0.0, 0.0, 0.2], [0.01, 0.0, 0.2], [0.05, 0.0, 0.2]];
        let offsets = vec![0, 2, 3];
        let got = contact_features(&points, &offsets, &cfg);
        assert!((got[0][0] - 0.05).abs() < 1e-7 && got[0][2] == 0.0);
        assert!((got[1][0] - 0.04).abs() < 1e-7);
        // Object 1's nearest other point is object 0's second point.
        assert!((got[2][0] + 0.04).abs() < 1e-7);
        assert_bit_identical(
            &got,
            &contact_features_brute_force(&points, &offsets, &cfg),
            "small",
        );
    }

    #[test]
    fn empty_objects_and_non_finite_points() {
        let cfg = ContactConfig::default();
        let points = vec![
            [0.0, 0.0, 0.5],
            [f32::NAN, 0.0, 0.5],
            [0.1, 0.0, 0.5],
            [f32::INFINITY, 0.0, 0.5],
        ];
        let offsets = vec![0, 0, 2, 2, 4, 4];
        let fast = contact_features(&points, &offsets, &cfg);
        assert_bit_identical(
            &fast,
            &contact_features_brute_force(&points, &offsets, &cfg),
            "empty objects",
        );
        assert!((fast[0][0] - 0.1).abs() < 1e-7);
        assert!(contact_features(&[], &[0], &cfg).is_empty());
        assert!(contact_features(&[], &[0, 0, 0], &cfg).is_empty());
    }

    #[test]
    fn bad_radius_gives_zero_vectors_and_validation_reports() {
        let points = vec![[0.0, 0.0, 0.5], [0.1, 0.0, 0.5]];
        for radius in [0.0, -1.0, f32::NAN] {
            let cfg = ContactConfig {
                radius,
                ground_z: Some(0.0),
            };
            assert!(cfg.validate().is_err());
            let got = contact_features(&points, &[0, 1, 2], &cfg);
            assert!(got.iter().flatten().all(|v| *v == 0.0));
        }
        assert!(ContactConfig::default().validate().is_ok());
        assert!(validate_offsets(2, &[0, 1]).is_err());
        assert!(validate_offsets(2, &[1, 2]).is_err());
        assert!(validate_offsets(2, &[0, 2, 1, 2]).is_err());
        assert!(validate_offsets(2, &[]).is_err());
        assert!(validate_offsets(2, &[0, 2]).is_ok());
    }

    #[test]
    fn far_apart_large_coordinates_still_match() {
        // Large coordinates force a coarser grid (cell cap); results must not change.
        let cfg = ContactConfig::default();
        let points = vec![
            [0.0, 0.0, 0.3],
            [0.2, 0.0, 0.3],
            [50_000.0, 0.0, 0.3],
            [50_000.1, 0.0, 0.3],
        ];
        let offsets = vec![0, 1, 2, 3, 4];
        assert_bit_identical(
            &contact_features(&points, &offsets, &cfg),
            &contact_features_brute_force(&points, &offsets, &cfg),
            "large coordinates",
        );
    }
}
