//! The two rotary codes of the official network, both in the "rotate half" layout: channel
//! `i < dh / 2` of a head is paired with channel `i + dh / 2`, and both turn by the same
//! phase, `x * cos + rotate_half(x) * sin` with `rotate_half(x) = [-x2, x1]`.
//!
//! - Frame code (temporal attention): phase `frame * 10000^(-2i / dh)`; prefix tokens sit at
//!   frame 0 (no rotation).
//! - Vertex code (spatial and per-object attention): the position's three coordinates, each
//!   times `n = max(1, (dh / 2) / 3)` frequencies `2^linspace(0, log2(n - 1), n)` (`[1]` for
//!   `n = 1`, `[1, 1]` for `n = 2`, as the official code computes them), laid out axis-major,
//!   cut or zero-padded to `dh / 2` phases.

use candle_core::{D, Device, Tensor};

/// Frequencies of the vertex code for `n` per axis.
pub(crate) fn vertex_freqs(n: usize) -> Vec<f32> {
    if n == 1 {
        return vec![1.0];
    }
    let max = ((n - 1) as f64).log2() as f32;
    let step = max / (n - 1) as f32;
    (0..n)
        .map(|i| {
            // torch.linspace computes the upper half from the end.
            let x = if i < n / 2 {
                i as f32 * step
            } else {
                max - (n - 1 - i) as f32 * step
            };
            2f32.powf(x)
        })
        .collect()
}

/// Phases `[rows, dh / 2]` of the vertex code of `positions [rows]` (network coordinates).
pub(crate) fn vertex_phases(positions: &[[f32; 3]], head_dim: usize, freqs: &[f32]) -> Vec<f32> {
    let half = head_dim / 2;
    let mut out = vec![0f32; positions.len() * half];
    for (r, p) in positions.iter().enumerate() {
        let row = &mut out[r * half..(r + 1) * half];
        let mut k = 0;
        'axes: for c in p {
            for f in freqs {
                if k == half {
                    break 'axes;
                }
                row[k] = c * f;
                k += 1;
            }
        }
    }
    out
}

/// Phases `[rows, dh / 2]` of the frame code: `prefix` rows at frame 0, then frames
/// `0..frames`.
pub(crate) fn frame_phases(prefix: usize, frames: usize, head_dim: usize) -> Vec<f32> {
    let half = head_dim / 2;
    let inv: Vec<f32> = (0..half)
        .map(|i| 1.0 / 10_000f32.powf((2 * i) as f32 / head_dim as f32))
        .collect();
    let mut out = vec![0f32; (prefix + frames) * half];
    for f in 0..frames {
        for (i, w) in inv.iter().enumerate() {
            out[(prefix + f) * half + i] = f as f32 * w;
        }
    }
    out
}

/// `(cos, sin)` tensors `[shape.., dh]` of phases `[rows, dh / 2]` (each phase used for both
/// halves of the head), reshaped to `shape` rows.
pub(crate) fn cos_sin(
    phases: &[f32],
    shape: &[usize],
    head_dim: usize,
    device: &Device,
) -> candle_core::Result<(Tensor, Tensor)> {
    let half = head_dim / 2;
    let rows = phases.len() / half;
    let mut cos = Vec::with_capacity(rows * head_dim);
    let mut sin = Vec::with_capacity(rows * head_dim);
    for r in 0..rows {
        let ph = &phases[r * half..(r + 1) * half];
        for _ in 0..2 {
            cos.extend(ph.iter().map(|p| p.cos()));
            sin.extend(ph.iter().map(|p| p.sin()));
        }
    }
    let mut dims = shape.to_vec();
    dims.push(head_dim);
    Ok((
        Tensor::from_vec(cos, dims.as_slice(), device)?,
        Tensor::from_vec(sin, dims.as_slice(), device)?,
    ))
}

/// `x * cos + rotate_half(x) * sin` for `x [G, H, L, dh]` and `cos, sin` broadcastable
/// `[G or 1, 1, L, dh]`.
pub(crate) fn apply(x: &Tensor, cos: &Tensor, sin: &Tensor) -> candle_core::Result<Tensor> {
    let dh = x.dim(D::Minus1)?;
    let half = dh / 2;
    let x1 = x.narrow(D::Minus1, 0, half)?;
    let x2 = x.narrow(D::Minus1, half, half)?;
    let rot = Tensor::cat(&[&x2.neg()?, &x1], D::Minus1)?;
    x.broadcast_mul(cos)? + rot.broadcast_mul(sin)?
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vertex_frequencies_match_the_official_grid() {
        // head width 64: 10 per axis, 2^linspace(0, log2 9, 10).
        let f = vertex_freqs(10);
        assert_eq!(f.len(), 10);
        assert!(
            (f[0] - 1.0).abs() < 1e-7 && (f[9] - 9.0).abs() < 1e-5,
            "{f:?}"
        );
        assert_eq!(vertex_freqs(2), vec![1.0, 1.0]);
        assert_eq!(vertex_freqs(1), vec![1.0]);
        // 30 phases padded to 32 with zeros.
        let ph = vertex_phases(&[[1.0, 2.0, 3.0]], 64, &f);
        assert_eq!(ph.len(), 32);
        assert_eq!((ph[10], ph[20], ph[30], ph[31]), (2.0, 3.0, 0.0, 0.0));
    }
}
