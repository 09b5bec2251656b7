//! The blocked path of the fused attention kernels, for key lists of
//! [`LONG_KEYS`](super::attention_keys::LONG_KEYS) or more: scores and weighted values as two
//! `gemm` products per scene, head and block of query rows.

use rayon::prelude::*;

use super::attention_keys::SceneKeys;
use super::attention_ops::{RotaryRows, exp_shifted, rotate};
use super::product::{Destination, Operand, product};
use crate::team;

/// Query rows per block of the blocked path: the block's scores (`rows x Tk`) stay in L2.
const LONG_KEYS_BLOCK_ROWS: usize = 64;

/// Consecutive query rows of every scene, `[B]`, if the rows are grouped by scene in order.
pub(super) fn scene_ranges(query_scene: &[u32], b: usize) -> Option<Vec<std::ops::Range<usize>>> {
    let mut ranges = vec![0..0; b];
    let mut r = 0;
    while r < query_scene.len() {
        let (s, start) = (query_scene[r] as usize, r);
        while r < query_scene.len() && query_scene[r] as usize == s {
            r += 1;
        }
        if s >= b || !ranges[s].is_empty() {
            return None;
        }
        ranges[s] = start..r;
    }
    Some(ranges)
}

/// Query rows of the blocked path ([`attend_long`]).
pub(super) struct LongQueries<'a> {
    /// Query row `r` starts at `q[r * stride]` (`D` values, heads side by side).
    pub(super) q: &'a [f32],
    pub(super) stride: usize,
    /// Rotary code of every query row.
    pub(super) rope: &'a RotaryRows,
    /// Query rows of every scene, `[B]`.
    pub(super) ranges: &'a [std::ops::Range<usize>],
    /// Additive bias per key `[B, Tk]`.
    pub(super) key_bias: &'a [f32],
    /// Per-head gate logits `[Nq, H]` (self-attention), output scaled by their sigmoid.
    pub(super) gate: Option<&'a [f32]>,
}

/// The blocked path: per scene, head and block of query rows, rotated queries, scores
/// `Q K^T / sqrt(dh) + bias` by one product, a row softmax, and `P V` by a second product
/// written straight into the head's output columns (then gated). Returns `[Nq, D]`.
pub(super) fn attend_long(
    queries: &LongQueries<'_>,
    heads: usize,
    d: usize,
    keys: &[SceneKeys],
    tk: usize,
) -> Vec<f32> {
    let dh = d / heads;
    let scale = 1.0 / (dh as f32).sqrt();
    let nq = queries.ranges.iter().map(|r| r.end).max().unwrap_or(0);
    let mut out = vec![0f32; nq * d];
    // Tasks: (scene, head, first row, rows); each writes its own rows x dh block.
    let mut tasks = Vec::new();
    for (s, r) in queries.ranges.iter().enumerate() {
        for h in 0..heads {
            let mut first = r.start;
            while first < r.end {
                let rows = LONG_KEYS_BLOCK_ROWS.min(r.end - first);
                tasks.push((s, h, first, rows));
                first += rows;
            }
        }
    }
    let out_ptr = Destination(out.as_mut_ptr());
    let task = |&(s, h, first, rows): &(usize, usize, usize, usize)| {
        let keys = &keys[s];
        let mut qb = vec![0f32; rows * dh];
        for (i, qr) in qb.chunks_exact_mut(dh).enumerate() {
            let at = (first + i) * queries.stride + h * dh;
            qr.copy_from_slice(&queries.q[at..at + dh]);
            let (cos, sin) = queries.rope.row(first + i);
            rotate(qr, cos, sin);
        }
        let bias = &queries.key_bias[s * tk..(s + 1) * tk];
        let mut sc = Vec::with_capacity(rows * tk);
        for _ in 0..rows {
            sc.extend_from_slice(bias);
        }
        let ks = keys.stride;
        let kt = &keys.kt[h * dh * ks..(h + 1) * dh * ks];
        // SAFETY: qb is [rows, dh], kt [dh, ks >= tk] (tk columns read) and sc [rows, tk], all
        // row-major and of exactly those lengths; sc is read (the bias) and overwritten.
        unsafe {
            product(
                (rows, tk, dh),
                sc.as_mut_ptr(),
                tk,
                true,
                Operand {
                    ptr: qb.as_ptr(),
                    rs: dh,
                    cs: 1,
                },
                Operand {
                    ptr: kt.as_ptr(),
                    rs: ks,
                    cs: 1,
                },
                scale,
                gemm::Parallelism::None,
            )
        };
        for row in sc.chunks_exact_mut(tk) {
            let inv = 1.0 / exp_shifted(row);
            row.iter_mut().for_each(|x| *x *= inv);
        }
        let v = &keys.v[h * tk * dh..(h + 1) * tk * dh];
        // SAFETY: sc is [rows, tk], v [tk, dh]; the destination is rows x dh values of `out`
        // at rows first.. (row stride d) and columns h * dh.., a block no other task touches
        // (tasks differ in rows or head columns), inside `out` (nq * d values).
        unsafe {
            let dst = out_ptr.at(first * d + h * dh);
            product(
                (rows, dh, tk),
                dst,
                d,
                false,
                Operand {
                    ptr: sc.as_ptr(),
                    rs: tk,
                    cs: 1,
                },
                Operand {
                    ptr: v.as_ptr(),
                    rs: dh,
                    cs: 1,
                },
                1.0,
                gemm::Parallelism::None,
            );
            if let Some(gate) = queries.gate {
                for i in 0..rows {
                    let r = first + i;
                    let w = 1.0 / (1.0 + (-gate[r * heads + h]).exp());
                    let o = std::slice::from_raw_parts_mut(dst.add(i * d), dh);
                    o.iter_mut().for_each(|x| *x *= w);
                }
            }
        };
    };
    if tasks.len() > 1 && team::parts() > 1 {
        team::run(|part, parts| {
            tasks[team::part_range(tasks.len(), part, parts, 1)]
                .iter()
                .for_each(task)
        });
    } else if tasks.len() > 1 && rayon::current_num_threads() > 1 {
        tasks.par_iter().for_each(task);
    } else {
        tasks.iter().for_each(task);
    }
    out
}
