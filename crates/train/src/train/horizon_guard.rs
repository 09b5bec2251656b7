//! The key figures' MOVi-B horizons and the guard on a candidate's translation RMSE at each:
//! the change against the reference by horizon and the bound it must stay within. Shared by
//! the comparison ([`super::compare`]) and the planner clause ([`super::planner_record`]).

/// MOVi-B horizons of the key figures, seconds.
pub const HORIZONS_S: [f64; 4] = [0.5, 1.0, 2.0, 4.0];

/// The fresh-scene guard: the fresh split's translation RMSE may exceed the reference's by at
/// most this fraction at each horizon.
pub const FRESH_GUARD: f64 = 0.01;

/// Per horizon, the candidate's figure over the reference's minus 1.
pub fn change_by_horizon(reference: &[f64; 4], candidate: &[f64; 4]) -> [f64; 4] {
    std::array::from_fn(|i| candidate[i] / reference[i] - 1.0)
}

/// Whether a change stays within `bound` (a fraction) at every horizon.
pub fn within_at_every_horizon(changes: &[f64; 4], bound: f64) -> bool {
    changes.iter().all(|&c| c <= bound)
}
