//! Vectorised `exp`, `sigmoid` and `silu` over f32 slices, compiled for AVX-512, AVX2+FMA and
//! baseline x86-64 and chosen at run time for the CPU the process runs on (other
//! architectures use the portable loop, which the compiler still vectorises).
//!
//! `exp` is a range reduction `x = n ln 2 + r` with a degree-6 polynomial for `e^r` and `2^n`
//! built in the exponent bits: relative error below 2e-7 over the clamped range
//! `[-87.3, 88.3]` (results saturate outside it; `exp(-1e9)` gives 1.2e-38, not 0).

/// Below this many elements a map runs on the calling thread.
const PARALLEL_MIN: usize = 1 << 16;

#[inline(always)]
fn exp_lane(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    let x = x.clamp(-87.336_54, 88.376_26);
    let n = (x * LOG2E + 0.5).floor();
    let r = x - n * LN2_HI - n * LN2_LO;
    let mut p = 1.987_569_1e-4;
    p = p * r + 1.398_2e-3;
    p = p * r + 8.333_452e-3;
    p = p * r + 4.166_579_6e-2;
    p = p * r + 1.666_666_5e-1;
    p = p * r + 0.5;
    let e = p * r * r + r + 1.0;
    e * pow2(n)
}

/// `2^n` for an integral `n` in `[-126, 128]`, built in the exponent bits without a float to
/// integer conversion (Rust's saturating `as i32` stops the compiler from vectorising the
/// loop): `n + 127 + 2^23` holds `n + 127` in its low mantissa bits.
#[inline(always)]
fn pow2(n: f32) -> f32 {
    const SHIFTED_BIAS: f32 = 127.0 + 8_388_608.0;
    const MAGIC_BITS: u32 = 0x4B00_0000;
    f32::from_bits((n + SHIFTED_BIAS).to_bits().wrapping_sub(MAGIC_BITS) << 23)
}

#[inline(always)]
fn sigmoid_lane(x: f32) -> f32 {
    1.0 / (1.0 + exp_lane(-x))
}

#[inline(always)]
fn silu_lane(x: f32) -> f32 {
    x * sigmoid_lane(x)
}

/// Defines `$name(&mut [f32])` applying `$lane` to every element, dispatched at run time.
macro_rules! dispatched_map {
    ($name:ident, $lane:ident, $doc:literal) => {
        #[doc = $doc]
        pub fn $name(x: &mut [f32]) {
            #[inline(always)]
            fn body(x: &mut [f32]) {
                for v in x.iter_mut() {
                    *v = $lane(*v);
                }
            }
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f")]
                unsafe fn avx512(x: &mut [f32]) {
                    body(x)
                }
                #[target_feature(enable = "avx2,fma")]
                unsafe fn avx2(x: &mut [f32]) {
                    body(x)
                }
                if std::arch::is_x86_feature_detected!("avx512f") {
                    // SAFETY: the CPU supports AVX-512F (checked just above).
                    return unsafe { avx512(x) };
                }
                if std::arch::is_x86_feature_detected!("avx2")
                    && std::arch::is_x86_feature_detected!("fma")
                {
                    // SAFETY: the CPU supports AVX2 and FMA (checked just above).
                    return unsafe { avx2(x) };
                }
            }
            body(x)
        }
    };
}

dispatched_map!(exp_slice, exp_lane, "`x <- exp(x)` element-wise.");
dispatched_map!(
    sigmoid_slice,
    sigmoid_lane,
    "`x <- 1 / (1 + exp(-x))` element-wise."
);
dispatched_map!(
    silu_slice,
    silu_lane,
    "`x <- x / (1 + exp(-x))` element-wise."
);

/// Applies `f` (one of the maps above) to `x`, split over rayon's pool when `x` is large.
pub fn par_map(x: &mut [f32], f: fn(&mut [f32])) {
    use rayon::prelude::*;
    if x.len() < PARALLEL_MIN || rayon::current_num_threads() < 2 {
        f(x)
    } else {
        x.par_chunks_mut(PARALLEL_MIN / 4).for_each(f)
    }
}

/// Element count above which [`row_blocks`] splits its rows over rayon's pool.
const ROWS_PARALLEL_MIN: usize = 1 << 15;

/// Runs `f(first_row, block)` over consecutive blocks of whole rows of `out` (rows of `n`
/// values), in parallel when `out` is large, and returns the sum of the `[n]` column partials
/// the blocks return (a reduction over rows, such as a bias gradient).
pub fn row_blocks(
    out: &mut [f32],
    n: usize,
    f: impl Fn(usize, &mut [f32]) -> Vec<f32> + Sync,
) -> Vec<f32> {
    use rayon::prelude::*;
    let block_rows = (ROWS_PARALLEL_MIN / n.max(1)).max(1);
    let step = block_rows * n.max(1);
    let partials: Vec<Vec<f32>> =
        if out.len() < 2 * ROWS_PARALLEL_MIN || rayon::current_num_threads() < 2 {
            out.chunks_mut(step)
                .enumerate()
                .map(|(i, b)| f(i * block_rows, b))
                .collect()
        } else {
            out.par_chunks_mut(step)
                .enumerate()
                .map(|(i, b)| f(i * block_rows, b))
                .collect()
        };
    let mut sum = vec![0f32; n];
    for p in &partials {
        axpy(&mut sum, 1.0, p);
    }
    sum
}

/// `y[j] += a * x[j]` over two equal-length slices (the compiler vectorises the loop for the
/// target features of the calling kernel).
#[inline(always)]
pub fn axpy(y: &mut [f32], a: f32, x: &[f32]) {
    for (y, x) in y.iter_mut().zip(x) {
        *y += a * *x;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn maps_match_libm() {
        let xs: Vec<f32> = (-2000..=2000).map(|i| i as f32 * 0.043).collect();
        let mut e = xs.clone();
        exp_slice(&mut e);
        let mut s = xs.clone();
        silu_slice(&mut s);
        let mut g = xs.clone();
        sigmoid_slice(&mut g);
        for (i, &x) in xs.iter().enumerate() {
            let want = (x as f64).exp();
            assert!(((e[i] as f64 - want) / want).abs() < 4e-7, "exp({x})");
            let sig = 1.0 / (1.0 + (-x as f64).exp());
            assert!((g[i] as f64 - sig).abs() < 3e-7, "sigmoid({x})");
            assert!((s[i] as f64 - x as f64 * sig).abs() < 1e-6 * (1.0 + x.abs() as f64));
        }
        let mut far = [-1.0e9f32, -100.0, 100.0];
        exp_slice(&mut far);
        assert!(far[0] < 1e-37 && far[1] < 1e-37 && far[2].is_finite());
        let mut big = [-1.0e9f32, 1.0e9];
        silu_slice(&mut big);
        assert!(big[0].abs() < 1e-20 && big[1] == 1.0e9);
    }
}
