//! Training loops, evaluation, baselines and reports for Dynaserve's world models.

pub mod train;
