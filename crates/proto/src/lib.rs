//! Generated gRPC types for the Dynaserve WorldModel API (dynaserve.v1).
