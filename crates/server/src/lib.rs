//! The Dynaserve inference server: continuous batching scheduler, streamed rollouts, gRPC (tonic) and HTTP (axum) front ends, Prometheus metrics.
