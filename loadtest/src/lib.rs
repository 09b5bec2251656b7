//! `dynaserve-loadtest`: a load generator for Dynaserve servers.
//!
//! It speaks the real APIs (gRPC, and HTTP JSON with Server-Sent Events, both through
//! `dynaserve-client`) or runs the model in-process with the server's batching rule,
//! and reports throughput (scene-steps/s, object-steps/s, requests/s), latency percentiles per
//! step (time between frames of a stream), per request and to the first frame, errors by
//! status code, and the server's batch-size and queue-wait distributions taken from the
//! difference of two `/metrics` scrapes.
//!
//! - [`run`]: load modes ([`run::Mode`]: streams, predict, poisson, ramp, soak) and the driver
//!   [`run::run_target`];
//! - [`rss`]: the server's resident memory during a soak;
//! - [`report`]: report types, text tables, A/B ratios, the HTML chart;
//! - [`scenes`]: scene files and the client crate's seeded random scenes;
//! - [`transport`]: gRPC and HTTP callers; [`inprocess`]: the no-server baseline;
//! - [`recorder`]: per-level counters; [`stats`]: percentiles (the `/metrics` histograms are
//!   read with `dynaserve_client::prom`);
//! - [`fairness`]: interactive step latency alone and beside bulk calls;
//! - [`spawn`]: launching a server as a child process; [`cli`]: the command line.

pub mod cli;
pub mod fairness;
pub mod generate_mode;
pub mod inprocess;
pub mod recorder;
pub mod report;
pub mod rss;
pub mod run;
pub mod scenes;
pub mod spawn;
pub mod stats;
pub mod transport;
