//! The encoder's MLPs for inference as one CPU pass per block of rows: gather each row's input
//! (optional leading values such as a neighbour's offset from its centre, then a source row
//! picked by index), a two-layer SiLU MLP through `gemm` on block-sized buffers, and the
//! maximum over each group of consecutive rows. One kernel serves the point MLP (no index, no
//! leading values, groups of one) and both set-abstraction levels.
//!
//! The composition it replaces materialises the gathered rows, their concatenation with the
//! offsets, two zero-initialised products, the biased SiLU and the pooled maximum as whole
//! tensors (tens of megabytes per batch, each a pass through memory and one synchronisation of
//! the thread pool). Here a block of about [`BLOCK_ROWS`] rows stays in the L2 cache from
//! gather to pooled output, and the first layer's bias is the product's initial value. No
//! gradient: for inference only (training keeps the composition).

use candle_core::{CpuStorage, CustomOp1, Layout, Shape};

use super::pool::group_max_value;
use super::product::{Operand, product};
use super::simd::silu_slice;
use super::storage::f32_slice;
use crate::team;

/// Input rows per block: the block's input, hidden and output buffers (about 128 KiB at the
/// small model's widths) stay in the L2 cache.
pub const BLOCK_ROWS: usize = 256;

/// Below this many multiply-adds a call outside the compute team runs on the calling thread.
const PARALLEL_MIN_MACS: usize = 1 << 20;

/// Host copy of a two-layer SiLU MLP's parameters, `out = W2 silu(W1 x + b1) + b2`, with the
/// weights stored transposed (`[in, out]` per layer), the layout `gemm` packs with vector
/// copies.
#[derive(Clone, Debug)]
pub struct MlpWeights {
    /// First layer transposed, `[input, hidden]`, row-major.
    w1t: Vec<f32>,
    /// First bias `[hidden]`.
    b1: Vec<f32>,
    /// Second layer transposed, `[hidden, out]`, row-major.
    w2t: Vec<f32>,
    /// Second bias `[out]`.
    b2: Vec<f32>,
}

/// `w [rows, cols]` (row-major) transposed to `[cols, rows]`.
fn transposed(w: &[f32], rows: usize) -> Vec<f32> {
    let cols = w.len() / rows.max(1);
    let mut t = vec![0f32; w.len()];
    for (r, row) in w.chunks_exact(cols.max(1)).enumerate() {
        for (c, &v) in row.iter().enumerate() {
            t[c * rows + r] = v;
        }
    }
    t
}

impl MlpWeights {
    /// From the layers' parameters as the network stores them: `w1 [hidden, input]`,
    /// `b1 [hidden]`, `w2 [out, hidden]`, `b2 [out]` (row-major).
    pub fn new(w1: &[f32], b1: Vec<f32>, w2: &[f32], b2: Vec<f32>) -> MlpWeights {
        MlpWeights {
            w1t: transposed(w1, b1.len()),
            w2t: transposed(w2, b2.len()),
            b1,
            b2,
        }
    }

    fn hidden(&self) -> usize {
        self.b1.len()
    }

    fn out(&self) -> usize {
        self.b2.len()
    }

    fn input(&self) -> usize {
        self.w1t.len() / self.hidden().max(1)
    }
}

/// One grouped-MLP pass: applied to a source tensor `[R, C]` it gives `[rows / group, out]`,
/// where input row `r` is `[lead[r] (lead_dim values), source[index[r]] (C values)]`.
pub struct GroupedMlp<'a> {
    /// The MLP (`input = lead_dim + C`).
    pub mlp: &'a MlpWeights,
    /// Source row of every input row, `[rows]`; `None` reads source row `r` for input row `r`.
    pub index: Option<&'a [u32]>,
    /// Values placed before the source row, `[rows, lead_dim]` (empty when `lead_dim` is 0).
    pub lead: &'a [f32],
    /// Leading values per row.
    pub lead_dim: usize,
    /// Consecutive rows max-pooled into one output row (1: no pooling).
    pub group: usize,
}

impl GroupedMlp<'_> {
    /// Input rows, checked against the source's `r` rows of `c` values.
    fn rows(&self, r: usize, c: usize) -> candle_core::Result<usize> {
        let rows = match self.index {
            Some(ix) => ix.len(),
            None => r,
        };
        let name = self.name();
        if self.mlp.input() != self.lead_dim + c
            || self.mlp.w1t.len() != self.mlp.hidden() * self.mlp.input()
            || self.mlp.w2t.len() != self.mlp.out() * self.mlp.hidden()
        {
            candle_core::bail!(
                "{name}: MLP of {} inputs, {} hidden and {} outputs does not take {} leading + {c} source values",
                self.mlp.input(),
                self.mlp.hidden(),
                self.mlp.out(),
                self.lead_dim
            );
        }
        if self.group == 0 || !rows.is_multiple_of(self.group) {
            candle_core::bail!(
                "{name}: {rows} rows do not split into groups of {}",
                self.group
            );
        }
        if self.lead.len() != rows * self.lead_dim {
            candle_core::bail!(
                "{name}: {} leading values for {rows} rows of {}",
                self.lead.len(),
                self.lead_dim
            );
        }
        if let Some(bad) = self
            .index
            .and_then(|ix| ix.iter().find(|&&i| i as usize >= r))
        {
            candle_core::bail!("{name}: source row {bad} of {r}");
        }
        Ok(rows)
    }

    /// Computes the output rows of the groups starting at `first_group` into `out` (whole
    /// output rows), with `scratch` as the block's buffers.
    fn block(
        &self,
        src: &[f32],
        c: usize,
        first_group: usize,
        out: &mut [f32],
        scratch: &mut Scratch,
    ) {
        let (m, g) = (self.mlp, self.group);
        let (input, hidden, n_out) = (m.input(), m.hidden(), m.out());
        let groups = out.len() / n_out;
        let (row0, rows) = (first_group * g, groups * g);
        // The input rows: straight from the source when there is nothing to gather.
        let direct = self.index.is_none() && self.lead_dim == 0;
        let x: &[f32] = if direct {
            &src[row0 * c..(row0 + rows) * c]
        } else {
            let (x, ld) = (&mut scratch.x, self.lead_dim);
            x.resize(rows * input, 0.0);
            for (i, row) in x.chunks_exact_mut(input).enumerate() {
                let r = row0 + i;
                let (lead, rest) = row.split_at_mut(ld);
                copy_short(lead, &self.lead[r * ld..(r + 1) * ld]);
                let s = self.index.map_or(r, |ix| ix[r] as usize);
                copy_short(rest, &src[s * c..(s + 1) * c]);
            }
            x
        };
        let h = &mut scratch.h;
        h.clear();
        for _ in 0..rows {
            h.extend_from_slice(&m.b1);
        }
        // SAFETY: x is [rows, input], h [rows, hidden] and w1t [input, hidden], all row-major
        // and of exactly those lengths (checked in `rows` and built above).
        unsafe {
            product(
                (rows, hidden, input),
                h.as_mut_ptr(),
                hidden,
                true,
                Operand {
                    ptr: x.as_ptr(),
                    rs: input,
                    cs: 1,
                },
                Operand {
                    ptr: m.w1t.as_ptr(),
                    rs: hidden,
                    cs: 1,
                },
                1.0,
                gemm::Parallelism::None,
            )
        };
        silu_slice(h);
        let y = &mut scratch.y;
        y.resize(rows * n_out, 0.0);
        // SAFETY: h is [rows, hidden], y [rows, out] and w2t [hidden, out], row-major; the
        // product overwrites y without reading it.
        unsafe {
            product(
                (rows, n_out, hidden),
                y.as_mut_ptr(),
                n_out,
                false,
                Operand {
                    ptr: h.as_ptr(),
                    rs: hidden,
                    cs: 1,
                },
                Operand {
                    ptr: m.w2t.as_ptr(),
                    rs: n_out,
                    cs: 1,
                },
                1.0,
                gemm::Parallelism::None,
            )
        };
        let gn = g * n_out;
        for (o, grp) in out.chunks_exact_mut(n_out).zip(y.chunks_exact(gn)) {
            group_max_value(grp, &m.b2, n_out, o);
        }
    }
}

/// `dst.copy_from_slice(src)` for the few dozen values of one gathered row, in 8-value moves
/// the compiler inlines (a `memcpy` call per row and operand was 3-4% of a step).
#[inline(always)]
fn copy_short(dst: &mut [f32], src: &[f32]) {
    let mut d = dst.chunks_exact_mut(8);
    let mut s = src.chunks_exact(8);
    for (a, b) in (&mut d).zip(&mut s) {
        if let (Ok(a), Ok(b)) = (<&mut [f32; 8]>::try_from(a), <&[f32; 8]>::try_from(b)) {
            *a = *b;
        }
    }
    for (a, b) in d.into_remainder().iter_mut().zip(s.remainder()) {
        *a = *b;
    }
}

/// One block's buffers: gathered inputs, hidden activations and unpooled outputs.
#[derive(Default)]
struct Scratch {
    x: Vec<f32>,
    h: Vec<f32>,
    y: Vec<f32>,
}

impl CustomOp1 for GroupedMlp<'_> {
    fn name(&self) -> &'static str {
        "grouped-mlp"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        use rayon::prelude::*;
        let src = f32_slice(self.name(), s, l)?;
        let (r, c) = l.shape().dims2()?;
        let rows = self.rows(r, c)?;
        let n_out = self.mlp.out();
        let groups = rows / self.group;
        let mut out = vec![0f32; groups * n_out];
        let block_groups = (BLOCK_ROWS / self.group).max(1);
        let chunk = block_groups * n_out;
        let macs = rows * self.mlp.hidden() * (self.mlp.input() + n_out);
        if macs >= team::SPLIT_MIN_MACS && team::parts() > 1 {
            // Blocks shared out over the compute team (a one-scene step).
            team::split_mut(&mut out, chunk, |first, piece| {
                let mut scratch = Scratch::default();
                for (i, o) in piece.chunks_mut(chunk).enumerate() {
                    self.block(src, c, (first + i) * block_groups, o, &mut scratch);
                }
            });
        } else if macs < PARALLEL_MIN_MACS || rayon::current_num_threads() < 2 {
            let mut scratch = Scratch::default();
            for (i, o) in out.chunks_mut(chunk).enumerate() {
                self.block(src, c, i * block_groups, o, &mut scratch);
            }
        } else {
            out.par_chunks_mut(chunk)
                .enumerate()
                .for_each_init(Scratch::default, |scratch, (i, o)| {
                    self.block(src, c, i * block_groups, o, scratch)
                });
        }
        Ok((CpuStorage::F32(out), Shape::from((groups, n_out))))
    }
}

#[cfg(test)]
mod tests {
    use candle_core::{Device, Tensor};

    use super::*;
    use crate::kernels::test_data::{max_diff, random, uniform};

    /// The composition: gather, concatenate, linear, SiLU, linear, group maximum.
    fn composed(
        src: &Tensor,
        w: &[Tensor; 4],
        index: Option<&[u32]>,
        lead: &[f32],
        lead_dim: usize,
        group: usize,
    ) -> Tensor {
        let dev = Device::Cpu;
        let x = match index {
            Some(ix) => src
                .index_select(&Tensor::new(ix, &dev).unwrap(), 0)
                .unwrap(),
            None => src.clone(),
        };
        let rows = x.dim(0).unwrap();
        let x = if lead_dim > 0 {
            let l = Tensor::from_slice(lead, (rows, lead_dim), &dev).unwrap();
            Tensor::cat(&[&l, &x], 1).unwrap()
        } else {
            x
        };
        let h = x
            .matmul(&w[0].t().unwrap())
            .unwrap()
            .broadcast_add(&w[1])
            .unwrap()
            .silu()
            .unwrap();
        let y = h
            .matmul(&w[2].t().unwrap())
            .unwrap()
            .broadcast_add(&w[3])
            .unwrap();
        let n = y.dim(1).unwrap();
        y.reshape((rows / group, group, n)).unwrap().max(1).unwrap()
    }

    fn weights(input: usize, hidden: usize, out: usize, seed: u64) -> ([Tensor; 4], MlpWeights) {
        let t = [
            random(&[hidden, input], seed, 0.5),
            random(&[hidden], seed + 1, 0.5),
            random(&[out, hidden], seed + 2, 0.5),
            random(&[out], seed + 3, 0.5),
        ];
        let v = |x: &Tensor| x.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let host = MlpWeights::new(&v(&t[0]), v(&t[1]), &v(&t[2]), v(&t[3]));
        (t, host)
    }

    #[test]
    fn matches_the_composition_for_the_three_encoder_uses() {
        // (source rows, source width, rows, lead, group, hidden, out): point MLP, a
        // set-abstraction level with a gather (enough rows for several blocks and threads),
        // and one pooling whole objects without a gather.
        for (seed, (r, c, rows, lead_dim, group, hidden, out)) in [
            (
                300usize, 15usize, 300usize, 0usize, 1usize, 32usize, 32usize,
            ),
            (700, 32, 2560, 3, 8, 64, 64),
            (96, 64, 96, 3, 32, 128, 128),
        ]
        .into_iter()
        .enumerate()
        {
            let seed = 10 * seed as u64;
            let src = random(&[r, c], seed, 2.0);
            let (w, host) = weights(lead_dim + c, hidden, out, seed + 1);
            let index: Option<Vec<u32>> = (lead_dim > 0 && rows != r)
                .then(|| (0..rows).map(|i| ((i * 7919 + 13) % r) as u32).collect());
            let lead = uniform(rows * lead_dim, seed + 5, 1.0);
            let op = GroupedMlp {
                mlp: &host,
                index: index.as_deref(),
                lead: &lead,
                lead_dim,
                group,
            };
            let fused = src.apply_op1_no_bwd(&op).unwrap();
            let want = composed(&src, &w, index.as_deref(), &lead, lead_dim, group);
            assert_eq!(fused.dims(), want.dims());
            let d = max_diff(&fused, &want);
            assert!(d < 1e-4, "case {seed}: max difference {d}");
        }
    }

    #[test]
    fn inconsistent_shapes_are_errors() {
        let src = random(&[10, 4], 1, 1.0);
        let (_, host) = weights(7, 8, 5, 2);
        let lead = [0f32; 12 * 3];
        let bad_index = [0u32, 1, 2, 10];
        let ok_index: Vec<u32> = (0..12).map(|i| i % 10).collect();
        let cases = [
            // source row out of range
            (Some(&bad_index[..]), &lead[..12], 3, 2),
            // rows not a multiple of the group
            (Some(&ok_index[..]), &lead[..], 3, 5),
            // wrong number of leading values
            (Some(&ok_index[..]), &lead[..30], 3, 4),
            // MLP input does not match lead + source width
            (Some(&ok_index[..]), &lead[..24], 2, 4),
        ];
        for (index, lead, lead_dim, group) in cases {
            let op = GroupedMlp {
                mlp: &host,
                index,
                lead,
                lead_dim,
                group,
            };
            assert!(src.apply_op1_no_bwd(&op).is_err());
        }
    }
}
