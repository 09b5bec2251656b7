//! Training loops, evaluation, baselines and reports for Dynaserve's world models.

pub mod cli;
pub mod eval;
pub mod ledger;
pub mod parity;
pub mod physi;
pub mod throughput;
pub mod train;
