//! One call shape for the `gemm` products of the CPU kernels (row-major, f32): the crate's
//! nineteen positional arguments in one place.

/// A matrix operand: first element and strides in elements.
#[derive(Clone, Copy)]
pub(crate) struct Operand {
    /// First element.
    pub ptr: *const f32,
    /// Distance between consecutive rows.
    pub rs: usize,
    /// Distance between consecutive columns.
    pub cs: usize,
}

/// `dst [m, n] = (read ? dst : 0) + scale * lhs [m, k] x rhs [k, n]`; `dst` has unit column
/// stride and row stride `dst_rs`. Without `read` the destination is written, never read.
///
/// # Safety
///
/// Every operand must address valid memory for its shape and strides, and `dst` must not
/// overlap `lhs` or `rhs` (nor, with parallel `par`, any memory another thread writes).
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn product(
    (m, n, k): (usize, usize, usize),
    dst: *mut f32,
    dst_rs: usize,
    read: bool,
    lhs: Operand,
    rhs: Operand,
    scale: f32,
    par: gemm::Parallelism,
) {
    // SAFETY: forwarded from the caller's contract.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst,
            1,
            dst_rs as isize,
            read,
            lhs.ptr,
            lhs.cs as isize,
            lhs.rs as isize,
            rhs.ptr,
            rhs.cs as isize,
            rhs.rs as isize,
            if read { 1.0f32 } else { 0.0f32 },
            scale,
            false,
            false,
            false,
            par,
        )
    }
}
