//! Physics scenario generators: scenes that each isolate one behaviour (`rest`, `drop`,
//! `slide`, `collide`, `stack-hit`) with MOVi-B's shapes, materials, floor and gravity, and
//! `physics-mix`, which draws one of them per scene.
//!
//! Objects that start on the floor or on each other are first settled in a separate rapier
//! world (dropped from 1 cm with zero velocity and stepped until every body is still), so
//! they start on a stable face at the equilibrium of rapier's soft contacts. Every scene's
//! scenario and variant is returned with it ([`crate::SceneLabel`]) and recorded in the manifest.
//!
//! - `parameters`: the scenarios, `rest` arrangements and the ranges scenes are drawn from;
//! - `placement`: drawing objects and settling their starting poses;
//! - `sample`: one sampler per scenario and [`sample_scenario`];
//! - `push`: the `push` scenario's objects and its pusher's random smooth path.

mod parameters;
mod placement;
mod push;
mod sample;

pub use parameters::{MaterialRanges, Materials, RestVariant, Scenario, ScenarioParameters};
pub use sample::sample_scenario;
