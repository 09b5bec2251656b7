//! PhysiFormer training and evaluation on mesh datasets (`docs/physiformer.md`):
//! [`train`] (`dynaserve train --config` with `architecture = "physiformer"`), [`eval`]
//! (`dynaserve eval --model` on a PhysiFormer checkpoint) and [`data`]; the official
//! data and metrics in [`official_data`] (with [`npz`]), [`official_metrics`],
//! [`official_eval`].

pub mod data;
pub mod eval;
pub mod npz;
pub mod official_data;
pub mod official_eval;
pub mod official_metrics;
pub mod train;
