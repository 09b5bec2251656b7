//! Load generator for Dynaserve (in progress).
fn main() {}
