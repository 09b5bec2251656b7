#!/usr/bin/env bash
# Builds the CUDA binary from nothing on a machine without CUDA: installs the toolkit from
# NVIDIA's wheels (toolkit.sh), builds `--features cuda` into target/cuda-build, and checks
# that the binary starts and, where there is no NVIDIA driver, refuses `--device cuda` naming
# it. Prints the time of each stage.
#
#   deploy/cuda/build.sh        # then: target/cuda/run.sh target/cuda-build/release/dynaserve ...
set -euo pipefail
cd "$(dirname "$0")/../.."
t0=$(date +%s)
deploy/cuda/toolkit.sh
t1=$(date +%s)
# shellcheck source=/dev/null
source target/cuda/env.sh
CARGO_TARGET_DIR=target/cuda-build cargo build --release --features cuda -p dynaserve
t2=$(date +%s)
bin=target/cuda-build/release/dynaserve
target/cuda/run.sh "$bin" --version
if ! ldconfig -p 2>/dev/null | grep -q 'libcuda\.so\.1 '; then
  out=$(RUST_BACKTRACE=0 target/cuda/run.sh "$bin" serve --device cuda \
    --grpc-addr 127.0.0.1:0 --http-addr 127.0.0.1:0 2>&1 || true)
  echo "$out" | head -1
  echo "$out" | grep -q 'no NVIDIA driver' || { echo "expected a refusal naming the driver"; exit 1; }
fi
echo "cuda build: toolkit $((t1 - t0)) s, cargo build $((t2 - t1)) s"
