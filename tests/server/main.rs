//! End-to-end tests of `dynaserve serve` against a real server on 127.0.0.1 with a real
//! RigidFormer loaded from disk (the shipped checkpoint when present, otherwise a randomly
//! initialised one saved to a temporary directory).
//!
//! One test binary (one link of the server and the model), its tests in modules by concern:
//! [`rollouts`] (every protocol agrees with the in-process rollout), [`admission`] (slots,
//! deadlines, overload), [`invalid_inputs`], [`metrics`] and [`examples`].

#[path = "../common/mod.rs"]
mod common;

mod admission;
mod examples;
mod fairness;
mod invalid_inputs;
mod metrics;
mod rollouts;
mod trained_ranges;
