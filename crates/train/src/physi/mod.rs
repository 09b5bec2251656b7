//! PhysiFormer training and evaluation on mesh datasets (`docs/physiformer.md`):
//! [`train`] (`dynaserve train --config` with `architecture = "physiformer"`), [`eval`]
//! (`dynaserve eval --model` on a PhysiFormer checkpoint) and [`data`].

pub mod data;
pub mod eval;
pub mod train;
