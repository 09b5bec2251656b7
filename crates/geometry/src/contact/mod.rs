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
//!
//! Modules: `config` (what a search is given), `hit` (what it returns per point),
//! `brute_force` (the reference), `grid` (boxes and per-object grids) and `search` (the grid
//! search and its workspace).

mod brute_force;
mod config;
mod grid;
mod hit;
mod search;

pub use brute_force::{contact_features_brute_force, contact_hits_brute_force};
pub use config::{ContactConfig, validate_offsets};
pub use hit::{ContactHit, ContactSource};
pub use search::{
    ContactWorkspace, PARALLEL_MIN_POINTS, contact_features, contact_features_into, contact_hits,
};

#[cfg(test)]
mod tests;
