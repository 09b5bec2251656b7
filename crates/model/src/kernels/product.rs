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

// SAFETY: an operand is a read-only view; the kernels that share one between threads never
// write through it, and its storage outlives the product (the callers' contracts).
unsafe impl Send for Operand {}
// SAFETY: as above.
unsafe impl Sync for Operand {}

/// A destination matrix's first element, shared by the threads that write disjoint parts of
/// it.
#[derive(Clone, Copy)]
pub(crate) struct Destination(pub *mut f32);

// SAFETY: every user splits the destination into disjoint column or row ranges per thread and
// joins the threads before the buffer is read or freed.
unsafe impl Send for Destination {}
// SAFETY: as above.
unsafe impl Sync for Destination {}

impl Destination {
    /// The element `offset` places past the first (taking `self` whole, so a closure that
    /// calls this captures the shareable wrapper, not the raw pointer).
    ///
    /// # Safety
    ///
    /// The offset must stay inside the destination's allocation.
    pub unsafe fn at(self, offset: usize) -> *mut f32 {
        // SAFETY: forwarded from the caller's contract.
        unsafe { self.0.add(offset) }
    }
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
