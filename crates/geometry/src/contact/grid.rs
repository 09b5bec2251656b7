//! The broad phase's boxes and the dense uniform grid over one object's points.

use crate::Point;

/// Broad-phase and grid margin: boxes are expanded and cells sized by `radius * MARGIN`, so
/// that rounding can never hide a candidate the brute force would see.
pub(super) const MARGIN: f32 = 1.05;

/// Maximum grid cells along one axis; the cell edge grows for very large scenes so that cell
/// coordinates stay exact enough in `f32`.
pub(super) const MAX_CELLS_PER_AXIS: f32 = 65536.0;

#[derive(Clone, Copy, Debug)]
pub(super) struct Aabb {
    pub(super) lo: [f32; 3],
    pub(super) hi: [f32; 3],
}

impl Aabb {
    pub(super) const EMPTY: Aabb = Aabb {
        lo: [f32::INFINITY; 3],
        hi: [f32::NEG_INFINITY; 3],
    };

    pub(super) fn is_empty(&self) -> bool {
        self.lo[0] > self.hi[0]
    }

    #[inline(always)]
    pub(super) fn grow_point(&mut self, p: &Point) {
        for (d, v) in p.iter().enumerate() {
            self.lo[d] = self.lo[d].min(*v);
            self.hi[d] = self.hi[d].max(*v);
        }
    }

    pub(super) fn grow_box(&mut self, b: &Aabb, pad: f32) {
        for d in 0..3 {
            self.lo[d] = self.lo[d].min(b.lo[d] - pad);
            self.hi[d] = self.hi[d].max(b.hi[d] + pad);
        }
    }

    /// False for NaN coordinates.
    #[inline(always)]
    pub(super) fn contains(&self, p: &Point) -> bool {
        (0..3).all(|d| p[d] >= self.lo[d] && p[d] <= self.hi[d])
    }
}

/// One point in a grid: its coordinates and its index into `points`.
#[derive(Clone, Copy, Debug)]
pub(super) struct Entry {
    pub(super) p: Point,
    pub(super) index: u32,
}

/// The dense uniform grid over one object's searchable points. Cells are indexed
/// `base + (z * ny + y) * nx + x`, so a row of three cells is one contiguous range of the
/// shared entry array.
#[derive(Clone, Copy, Debug)]
pub(super) struct ObjectGrid {
    pub(super) origin: [f32; 3],
    pub(super) inv_cell: f32,
    pub(super) dims: [i64; 3],
    pub(super) base: usize,
    /// The grid's points' box expanded by the search margin: no point outside it can have a
    /// candidate in this grid.
    pub(super) reach: Aabb,
}

/// `floor(v)` for the cell coordinate range used here (`|v|` far below `2^63`); saturates.
#[inline(always)]
pub(super) fn floor_i64(v: f32) -> i64 {
    let t = v as i64;
    if (t as f32) > v { t - 1 } else { t }
}

impl ObjectGrid {
    /// Cell index of one of the grid's own points (always inside the grid: its scaled offsets
    /// are `>= 0`, so truncation is the floor; clamped for safety).
    #[inline(always)]
    pub(super) fn bucket_of(&self, p: &Point) -> usize {
        let c = |d: usize| {
            (((p[d] - self.origin[d]) * self.inv_cell) as i64).clamp(0, self.dims[d] - 1)
        };
        self.base + ((c(2) * self.dims[1] + c(1)) * self.dims[0] + c(0)) as usize
    }
}
