//! The key layout of the attention forward kernels: one scene's keys rotated and transposed
//! once, read by the row kernel of [`super::attention`] and the blocked path of
//! [`super::attention_long`].

use super::attention_ops::{RotaryRows, rotate};

/// Key count from which [`CrossAttention`](super::attention_ops::CrossAttention) and
/// [`SelfAttention`](super::attention_ops::SelfAttention) run as blocked products
/// (`gemm`) instead of one query row at a time: the row kernel re-reads its scores for every
/// channel, which costs more than packing once the key list is long (the wrecking ball's
/// anchor queries see 675 keys, its decoder tokens 225). Lowered to 48 (so that a MOVi-sized
/// scene's 54 anchor keys take the blocked path) a batch-8 step measured 1.02-1.07x in one
/// window and 0.99-1.14x in a noisier one: not clearly better, so kept.
pub const LONG_KEYS: usize = 128;

/// One scene's keys, rotated and transposed `[H, dh, stride]` (key `j` of channel `d` at
/// `(h * dh + d) * stride + j`, zeros past `Tk`), and values `[H, Tk, dh]`.
pub(super) struct SceneKeys {
    pub(super) kt: Vec<f32>,
    pub(super) v: Vec<f32>,
    pub(super) stride: usize,
}

/// Row stride of the transposed keys of `tk` keys: short lists are padded to a multiple of 16
/// so that a query row's scores fit a fixed number of vector registers.
fn key_stride(tk: usize) -> usize {
    if tk < LONG_KEYS {
        tk.next_multiple_of(16)
    } else {
        tk
    }
}

/// Where the keys and values of scene `s` are: row `j` of its keys starts at
/// `data[(s * tk + j) * stride + k_off]`, values at `.. + v_off`.
#[derive(Clone, Copy)]
pub(super) struct KeySource<'a> {
    pub(super) data: &'a [f32],
    pub(super) stride: usize,
    pub(super) k_off: usize,
    pub(super) v_off: usize,
    pub(super) tk: usize,
}

/// Rotates and transposes the keys of scene `s` of `src` into [`SceneKeys`] (`heads` of `dh`
/// channels, rotated by `rope`'s rows of that scene).
pub(super) fn scene_keys(
    src: KeySource<'_>,
    s: usize,
    heads: usize,
    dh: usize,
    rope: &RotaryRows,
) -> SceneKeys {
    let tk = src.tk;
    let stride = key_stride(tk);
    let mut kt = vec![0f32; heads * dh * stride];
    let mut v = vec![0f32; heads * tk * dh];
    let mut buf = vec![0f32; dh];
    for j in 0..tk {
        let row = (s * tk + j) * src.stride;
        let (cos, sin) = rope.row(s * tk + j);
        for h in 0..heads {
            buf.copy_from_slice(&src.data[row + src.k_off + h * dh..][..dh]);
            rotate(&mut buf, cos, sin);
            for (d, x) in buf.iter().enumerate() {
                kt[(h * dh + d) * stride + j] = *x;
            }
            v[(h * tk + j) * dh..][..dh]
                .copy_from_slice(&src.data[row + src.v_off + h * dh..][..dh]);
        }
    }
    SceneKeys { kt, v, stride }
}
