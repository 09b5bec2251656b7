//! The grid search of [`contact_features`] and [`contact_hits`]: broad phase, per-object grids,
//! the 3 x 3 x 3 neighbourhood search (in parallel for large scenes) and the per-thread
//! [`ContactWorkspace`] that keeps its scratch memory.

use std::cell::RefCell;

use rayon::prelude::*;

use super::config::{ContactConfig, validate_offsets};
use super::grid::{Aabb, Entry, MARGIN, MAX_CELLS_PER_AXIS, ObjectGrid, floor_i64};
use super::hit::{ContactHit, ContactSource, dist2, ground_fallback};
use crate::Point;

/// Scenes with at least this many points search in parallel on rayon's pool; smaller ones run
/// serially. Measured with the `contact/threshold` bench on an idle two-core machine, parallel
/// against serial: 1.82x at 4096 points (0.68 vs 1.23 ms), 1.66x at 13824, 1.64x at 32768,
/// and no gain at 512. (On the same machine kept busy by two training jobs, parallel was
/// slower at 4096 points and no faster above.) Inside a one-thread pool, such as a scene group
/// of a batched step, the search is serial anyway. Tune per deployment with
/// [`ContactWorkspace::with_parallel_threshold`].
pub const PARALLEL_MIN_POINTS: usize = 4096;

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
