//! Differentiable Kabsch projection as a candle custom op.
//!
//! Input: predicted anchor positions `[objects, K, 3]` (metres). The reference anchors
//! (`[objects, K, 3]`, body frame) are constants held by the op. Output `[objects, 12]`: the
//! row-major rotation `R` (9 values) then the translation `p` (3 values, metres) minimising
//! `sum_k |R a_ref_k + p - a_k|^2`. Forward: [`dynaserve_geometry::kabsch()`] per object (f64);
//! backward: [`dynaserve_geometry::kabsch_backward`] (closed form, finite for degenerate sets).
//! Objects run in parallel with rayon. CPU storage only: callers on other devices move the
//! (small) input to the CPU and the result back, both differentiable.

use candle_core::{CpuStorage, CustomOp1, Layout, Shape, Tensor};
use dynaserve_geometry::{KabschSolution, kabsch, kabsch_backward};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// The Kabsch custom op; holds the reference anchors.
#[derive(Clone, Debug)]
pub struct KabschOp {
    /// Reference anchors per object, `[objects][K]`, metres (body frame).
    pub reference: Vec<Vec<[f64; 3]>>,
}

impl KabschOp {
    /// Builds the op from reference anchors `[objects][K]`.
    pub fn new(reference: Vec<Vec<[f64; 3]>>) -> KabschOp {
        KabschOp { reference }
    }

    /// Applies the op: `target` `[objects, K, 3]` -> `[objects, 12]` (R row-major, then p).
    pub fn apply(&self, target: &Tensor) -> candle_core::Result<Tensor> {
        let dev = target.device().clone();
        if dev.is_cpu() {
            target.apply_op1(self.clone())
        } else {
            target
                .to_device(&candle_core::Device::Cpu)?
                .apply_op1(self.clone())?
                .to_device(&dev)
        }
    }

    fn solve(&self, targets: &[Vec<[f64; 3]>]) -> candle_core::Result<Vec<KabschSolution>> {
        targets
            .par_iter()
            .zip(&self.reference)
            .map(|(t, r)| kabsch(r, t, None).map_err(candle_core::Error::wrap))
            .collect()
    }
}

fn read_targets(data: &[f32], objects: usize, k: usize) -> Vec<Vec<[f64; 3]>> {
    (0..objects)
        .map(|o| {
            (0..k)
                .map(|i| {
                    let b = (o * k + i) * 3;
                    [data[b] as f64, data[b + 1] as f64, data[b + 2] as f64]
                })
                .collect()
        })
        .collect()
}

impl CustomOp1 for KabschOp {
    fn name(&self) -> &'static str {
        "kabsch"
    }

    fn cpu_fwd(
        &self,
        storage: &CpuStorage,
        layout: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let (objects, k, three) = layout.shape().dims3()?;
        if three != 3 || objects != self.reference.len() {
            candle_core::bail!(
                "kabsch op: input {:?} does not match {} reference objects",
                layout.shape(),
                self.reference.len()
            );
        }
        if self.reference.iter().any(|r| r.len() != k) {
            candle_core::bail!("kabsch op: reference anchor count differs from K = {k}");
        }
        let data = match storage {
            CpuStorage::F32(v) => v,
            _ => candle_core::bail!("kabsch op: expects f32 input"),
        };
        let data: Vec<f32> = match layout.contiguous_offsets() {
            Some((a, b)) => data[a..b].to_vec(),
            None => candle_core::bail!("kabsch op: input must be contiguous"),
        };
        let targets = read_targets(&data, objects, k);
        let sols = self.solve(&targets)?;
        let mut out = Vec::with_capacity(objects * 12);
        for s in &sols {
            for r in 0..3 {
                for c in 0..3 {
                    out.push(s.rotation[(r, c)] as f32);
                }
            }
            out.extend(s.translation.iter().map(|v| *v as f32));
        }
        Ok((CpuStorage::F32(out), Shape::from((objects, 12))))
    }

    fn bwd(
        &self,
        arg: &Tensor,
        _res: &Tensor,
        grad_res: &Tensor,
    ) -> candle_core::Result<Option<Tensor>> {
        let (objects, k, _) = arg.dims3()?;
        let dev = arg.device().clone();
        let data = arg
            .flatten_all()?
            .to_device(&candle_core::Device::Cpu)?
            .to_vec1::<f32>()?;
        let grad = grad_res
            .flatten_all()?
            .to_device(&candle_core::Device::Cpu)?
            .to_vec1::<f32>()?;
        let targets = read_targets(&data, objects, k);
        let sols = self.solve(&targets)?;
        let per_object: Vec<Vec<[f64; 3]>> = (0..objects)
            .into_par_iter()
            .map(|o| {
                let g = &grad[o * 12..(o + 1) * 12];
                let g_r = Matrix3::from_fn(|r, c| g[r * 3 + c] as f64);
                let g_p = Vector3::new(g[9] as f64, g[10] as f64, g[11] as f64);
                kabsch_backward(&self.reference[o], &targets[o], None, &sols[o], &g_r, &g_p).0
            })
            .collect();
        let flat: Vec<f32> = per_object
            .iter()
            .flatten()
            .flatten()
            .map(|v| *v as f32)
            .collect();
        Ok(Some(Tensor::from_vec(flat, (objects, k, 3), &dev)?))
    }
}
