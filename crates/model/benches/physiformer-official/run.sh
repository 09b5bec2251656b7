#!/usr/bin/env bash
# PhysiFormer at the published size (the official B network, 132.5 M parameters) on this
# machine: one denoiser call of a 49-frame, 356-vertex, 10-object scene and one 16-step Heun
# sample, the official code (PyTorch, float32 and its default bf16 autocast) and ours in turn,
# with each process's peak memory. Prints one JSON line per measurement and a summary table.
#
#   crates/model/benches/physiformer-official/run.sh OFFICIAL_CHECKOUT [WORK_DIR] [THREADS]
#
# OFFICIAL_CHECKOUT: a local copy of the official PhysiFormer repository. PYTHON (default
# python3) must have torch and numpy. WORK_DIR (default target/physiformer-official) receives
# the 530 MB random B checkpoint, its import and results.jsonl. Takes about 40 minutes on two
# cores; run it on an otherwise idle machine.
set -euo pipefail
cd "$(dirname "$0")/../../../.."
official=${1:?usage: run.sh OFFICIAL_CHECKOUT [WORK_DIR] [THREADS]}
work=${2:-target/physiformer-official}
threads=${3:-2}
py=${PYTHON:-python3}
here=crates/model/benches/physiformer-official
mkdir -p "$work"
work=$(cd "$work" && pwd)
out="$work/results.jsonl"
: > "$out"
if [ ! -f "$work/checkpoint-b.pt" ]; then
  "$py" "$here/official.py" make "$official" "$work"
fi
cargo build --release --bin dynaserve
if [ ! -f "$work/models/physiformer-b/config.json" ]; then
  target/release/dynaserve import physiformer --checkpoint "$work/checkpoint-b.pt" \
    --out "$work/models/physiformer-b"
fi
cargo bench -p dynaserve-model --bench official_denoise --no-run
ours() {
  PF_BENCH_DIR="$work" PF_BENCH_WHAT="$1" RAYON_NUM_THREADS="$threads" \
    cargo bench -q -p dynaserve-model --bench official_denoise 2>/dev/null | grep '^{' | tee -a "$out"
}
theirs() {
  "$py" "$here/official.py" time "$official" "$work" "$1" "$2" "$threads" 2>/dev/null | grep '^{' | tee -a "$out"
}
echo "== one denoiser call (3 repetitions each)"
theirs call none
ours call
theirs call bf16
echo "== one 16-step Heun sample (31 calls)"
theirs sample:16 none
ours sample:16
"$py" - "$out" <<'PY'
import json, statistics, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
print(f"{'implementation':<12} {'what':<10} {'dtype':<6} {'median s':>9} {'peak MiB':>9}")
for r in rows:
    dtype = "bf16" if r["amp"] == "bf16" else "f32"
    print(f"{r['impl']:<12} {r['what']:<10} {dtype:<6} {statistics.median(r['seconds']):>9.2f} {r['peak_rss_mib']:>9}")
PY
