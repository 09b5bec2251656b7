#!/usr/bin/env bash
# The GPU kit's one command (deploy/gpu-kit/README.md): on a Linux machine with an NVIDIA
# driver and no Rust, toolkit or network, checks the device against the CPU, generates a
# configuration's training data on the machine's cores, trains it for a wall-clock budget
# (checkpoint every minute; resumable), exports and evaluates the model, and writes every
# result as files of at most 16 MiB under --out. `--device cpu` runs the same stages on the CPU.
#
#   ./kit.sh --out OUT [--device cuda|cpu] [--config NAME] [--minutes M] [--resume DIR]
#            [--data-scale F] [--eval-scenes N] [--fresh-scenes N] [--suite-scenes N]
#            [--serve-batches LIST] [--train-batches LIST] [--train-presets LIST]
#            [--stages parity,data,throughput,train,eval] [--work DIR]
set -euo pipefail

KIT=$(cd "$(dirname "$0")" && pwd)
device=cuda config=rigidformer-small-r88 minutes=10 resume="" data_scale=1
eval_scenes=200 fresh_scenes=100 suite_scenes="" stages=parity,data,throughput,train,eval
serve_batches=1,8,32,128,256 train_batches=24,64,128,256 train_presets=small,paper
out="" work=""

usage() { sed -n '2,11p' "$0" | sed 's/^# \{0,1\}//'; exit "${1:-0}"; }
while [ $# -gt 0 ]; do
  case "$1" in
    --out) out=$2; shift 2 ;;
    --device) device=$2; shift 2 ;;
    --config) config=$2; shift 2 ;;
    --minutes) minutes=$2; shift 2 ;;
    --resume) resume=$2; shift 2 ;;
    --data-scale) data_scale=$2; shift 2 ;;
    --eval-scenes) eval_scenes=$2; shift 2 ;;
    --fresh-scenes) fresh_scenes=$2; shift 2 ;;
    --suite-scenes) suite_scenes=$2; shift 2 ;;
    --stages) stages=$2; shift 2 ;;
    --serve-batches) serve_batches=$2; shift 2 ;;
    --train-batches) train_batches=$2; shift 2 ;;
    --train-presets) train_presets=$2; shift 2 ;;
    --work) work=$2; shift 2 ;;
    -h | --help) usage 0 ;;
    *) echo "kit: unknown argument $1" >&2; usage 2 >&2 ;;
  esac
done
[ -n "$out" ] || { echo "kit: --out DIR is required" >&2; exit 2; }
cfg_file="$KIT/configs/$config.toml"
[ -f "$cfg_file" ] || { echo "kit: no configuration $config (configs/ holds $(cd "$KIT/configs" && ls -- *.toml | sed 's/\.toml$//' | tr '\n' ' '))" >&2; exit 2; }
mkdir -p "$out"
out=$(cd "$out" && pwd)
work=${work:-$out.work}
mkdir -p "$work"
work=$(cd "$work" && pwd)
mkdir -p "$work/results"
has() { case ",$stages," in *",$1,"*) return 0 ;; *) return 1 ;; esac; }

log="$out/kit.log"
: >"$log"
summary="$out/summary.txt"
: >"$summary"
say() { echo "$*" | tee -a "$summary"; }
stage_start=0
begin() { stage_start=$(date +%s); echo "== $1 ($(date -u +%H:%M:%S))" | tee -a "$log"; }
took() { echo $(($(date +%s) - stage_start)); }
# Runs the binary with its output in the log and on the terminal.
ds() { "$bin" "$@" 2>&1 | tee -a "$log"; }

# --- the binary and its libraries ------------------------------------------------------------
bin="$work/bin/dynaserve"
if [ -x "$KIT/dynaserve" ]; then
  bin="$KIT/dynaserve"
elif [ ! -x "$bin" ] || [ "$KIT/dynaserve.xz" -nt "$bin" ]; then
  mkdir -p "$work/bin"
  if command -v xz >/dev/null; then
    xz -dc "$KIT/dynaserve.xz" >"$bin.part"
  else
    python3 -c 'import lzma,shutil,sys; shutil.copyfileobj(lzma.open(sys.argv[1]), open(sys.argv[2], "wb"))' \
      "$KIT/dynaserve.xz" "$bin.part"
  fi
  chmod +x "$bin.part" && mv "$bin.part" "$bin"
fi
libs=""
if [ "${device%%:*}" = cuda ]; then
  # cuBLAS, cuRAND and the CUDA runtime (13.x) are not in the kit (cuBLAS alone is 600 MB):
  # found where the machine has them, a CUDA install or the NVIDIA wheels of a Python.
  ld=${LD_LIBRARY_PATH:-}
  roots="${ld//:/ } /usr/local/cuda/lib64 /usr/local/cuda/targets/x86_64-linux/lib /usr/lib/x86_64-linux-gnu"
  for py in python3 /opt/*/.venv/bin/python3; do
    command -v "$py" >/dev/null 2>&1 || continue
    roots="$roots $("$py" -c 'import site; print(" ".join(site.getsitepackages()))' 2>/dev/null || true)"
  done
  for lib in libcublas.so.13 libcublasLt.so.13 libcurand.so.10 libcudart.so.13; do
    dir=""
    for r in $roots; do
      [ -d "$r" ] || continue
      hit=$(find "$r" -maxdepth 4 -name "$lib" 2>/dev/null | head -1)
      if [ -n "$hit" ]; then dir=$(dirname "$hit"); break; fi
    done
    if [ -z "$dir" ]; then
      echo "kit: $lib not found; install the CUDA 13 runtime libraries (pip install nvidia-cublas nvidia-curand nvidia-cuda-runtime, or a CUDA 13 toolkit) or put their folder on LD_LIBRARY_PATH" >&2
      exit 3
    fi
    case ":$libs:" in *":$dir:"*) ;; *) libs="${libs:+$libs:}$dir" ;; esac
  done
fi
export LD_LIBRARY_PATH="${libs}${libs:+${LD_LIBRARY_PATH:+:}}${LD_LIBRARY_PATH:-}"
# Fonts for the PNG charts: the system's, else the copies the kit carries.
if ldd "$bin" 2>/dev/null | grep -q 'not found'; then
  export LD_LIBRARY_PATH="${LD_LIBRARY_PATH:+$LD_LIBRARY_PATH:}$KIT/lib"
fi
if ldd "$bin" 2>/dev/null | grep 'not found'; then
  echo "kit: $bin cannot load the libraries above" >&2
  exit 3
fi

cd "$work"
export RUST_BACKTRACE=0
ln -sfn "$KIT/models" models
ln -sfn "$KIT/configs" configs
cores=$(nproc)
say "dynaserve GPU kit: configuration $config on $device, $cores CPU cores, $(date -u +%Y-%m-%dT%H:%M:%SZ)"
say "binary: $("$bin" --version)"
[ "${device%%:*}" = cuda ] && command -v nvidia-smi >/dev/null &&
  say "gpu: $(nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | head -1)"
failed=0

# --- parity ----------------------------------------------------------------------------------
if has parity; then
  begin parity
  if ds parity --device "$device" --json "$work/results/parity.json"; then
    say "parity: $(grep -E '^(PASSED|FAILED)' "$log" | tail -1) ($(took) s)"
    grep -E '^  models/' "$log" | tail -2 | tee -a "$summary"
  else
    if grep -q 'cannot open it' "$log"; then
      say "parity: the device cannot be used: $(grep -m1 'cannot open it' "$log")"
      exit 3
    fi
    say "parity: FAILED ($(took) s; kit.log has the figures)"
    failed=1
  fi
fi

# --- data ------------------------------------------------------------------------------------
# Scales every --scenes of a recipe line by --data-scale (at least 1).
scaled() {
  local words=() prev=""
  for w in $1; do
    if [ "$prev" = --scenes ]; then
      w=$(awk -v n="$w" -v s="$data_scale" 'BEGIN { m = int(n * s + 0.5); print (m < 1 ? 1 : m) }')
    fi
    words+=("$w")
    prev=$w
  done
  echo "${words[@]}"
}
# Generates a split unless its directory already holds one.
generate() {
  local dir
  dir=$(echo "$*" | sed -n 's/.*--out \([^ ]*\).*/\1/p')
  [ -f "$dir/manifest.json" ] && return 0
  ds sim "$@" --threads "$cores" >/dev/null
}
if has data; then
  begin data
  recipe="$KIT/recipes/$config.txt"
  [ -f "$recipe" ] || { echo "kit: no data recipe recipes/$config.txt" >&2; exit 2; }
  n=0 splits=""
  while read -r line; do
    case "$line" in '' | '#'*) continue ;; esac
    # shellcheck disable=SC2046
    generate $(scaled "$line")
    n=$((n + 1))
  done <"$recipe"
  if has eval; then
    generate movi-b --scenes "$eval_scenes" --out data/movi-b/test --seed 2 --split test
    generate movi-b --scenes "$fresh_scenes" --out data/movi-b/check --seed 5 --split test
    splits=" and the MOVi-B test ($eval_scenes scenes) and fresh ($fresh_scenes) splits"
  fi
  say "data: $n training splits (scale $data_scale)$splits, $(du -sh data | cut -f1), $(took) s"
fi

# --- throughput ------------------------------------------------------------------------------
if has throughput; then
  begin throughput
  say "serving throughput, RigidFormer step (scene-steps/s):"
  for d in "$device" $([ "$device" = cpu ] || echo cpu); do
    ds throughput --device "$d" --batches "$serve_batches" --json "$work/results/throughput-$d.json" |
      grep -v '^| ---' | tee -a "$summary"
  done
  if [ "$device" != cpu ]; then
    ds throughput --device "$device" --batches "$serve_batches" --max-pass-objects 100000 \
      --json "$work/results/throughput-$device-one-pass.json" | grep -v '^| ---' | tee -a "$summary"
  fi
  # Training throughput: fresh models of each preset on the recipe's first split, 30 iterations.
  train_data=$(sed -n 's/.*--out \([^ ]*\).*/\1/p' "$KIT/recipes/$config.txt" | head -1)
  say "training throughput on $device ($train_data, 256-512 points per object):"
  say "| preset | batch | it/s | waiting for data |"
  for p in ${train_presets//,/ }; do
    for b in ${train_batches//,/ }; do
      t="throughput/$p-$b"
      rm -rf "runs/$t" && mkdir -p throughput
      printf '[data]\ntrain = "%s"\npoints_min = 256\npoints_max = 512\n[model]\npreset = "%s"\nfit_normalization = false\n[optim]\nbatch_size = %s\niterations = 1000000\n[run]\nout_dir = "runs/%s"\nloader_threads = %s\nprogress = false\nlog_every = 1000\n' \
        "$train_data" "$p" "$b" "$t" "$(( cores > 2 ? cores / 2 : 1 ))" >"$t.toml"
      line=$(ds train --config "$t.toml" --device "$device" --stop-after 30 | grep '^stopped at' || true)
      rate=$(echo "$line" | sed -n 's/.*(\([0-9.]*\) it\/s this session, \([0-9]*\)% of it waiting.*/\1 | \2%/p')
      say "| $p | $b | ${rate:-failed (kit.log)} |"
      rm -rf "runs/$t"
    done
  done
  say "throughput: $(took) s"
fi

# --- train -----------------------------------------------------------------------------------
run_dir=$(sed -n 's/^out_dir *= *"\(.*\)"/\1/p' "$cfg_file" | head -1)
run_dir=${run_dir:-runs/$config}
if has train; then
  begin train
  resume_flag=""
  if [ -n "$resume" ]; then
    if compgen -G "$resume/resume.tar.part-*" >/dev/null; then
      rm -rf "$run_dir"
      cat "$resume"/resume.tar.part-* | tar -xf - -C "$work"
    elif [ -d "$resume/checkpoint" ]; then
      rm -rf "$run_dir" && mkdir -p "$(dirname "$run_dir")" && cp -r "$resume" "$run_dir"
    else
      echo "kit: --resume $resume holds neither resume.tar.part-* nor checkpoint/" >&2
      exit 2
    fi
    resume_flag=--resume
  fi
  from=$(sed -n 's/.*"step": *\([0-9]*\).*/\1/p' "$run_dir/checkpoint/state.json" 2>/dev/null || true)
  ds train --config "configs/$config.toml" --device "$device" --minutes "$minutes" \
    --checkpoint-minutes 1 $resume_flag
  line=$(grep '^stopped at iteration' "$log" | tail -1)
  say "train: ${from:+resumed from iteration $from, }$line ($(took) s)"
  # What a later --resume needs: the run directory without its kept copies, in 15 MiB parts.
  rm -f "$out"/resume.tar.part-*
  tar -cf - --exclude='checkpoint.old' --exclude='checkpoint-*' -C "$work" "$run_dir" |
    split -b 15m -d -a 2 - "$out/resume.tar.part-"
  say "resume: $(ls "$out"/resume.tar.part-* | wc -l) part(s) in $out (--resume $out)"
fi

# --- export and evaluate ---------------------------------------------------------------------
if has eval; then
  begin eval
  rm -rf "$work/results/model" "$work/results/scorecard"
  mkdir -p "$work/results/scorecard"
  ds train export --run "$run_dir" --out "$work/results/model" --ema >/dev/null
  m="$work/results/model"
  sc="$work/results/scorecard"
  suite=()
  [ -n "$suite_scenes" ] && suite=(--suite-scenes "$suite_scenes")
  ds eval --model "$m" --device "$device" --data data/movi-b/test --step-sizes 1 --no-variants \
    --json "$sc/eval.json" --markdown "$sc/eval.md" >/dev/null
  ds eval --model "$m" --device "$device" --data data/movi-b/check --step-sizes 1 --no-variants \
    --json "$sc/fresh.json" >/dev/null
  ds eval --model "$m" --device "$device" --suite physics "${suite[@]}" \
    --json "$sc/physics-suite.json" --markdown "$sc/physics-suite.md" >/dev/null
  cp "$run_dir"/*.csv "$run_dir"/*.png "$work/results/" 2>/dev/null || true
  say "eval: exported (EMA) and scored in $(took) s; MOVi-B test:"
  awk '/^\*\*Translation RMSE/ { on = 1 } on && /^$/ && n++ > 0 { exit } on' "$sc/eval.md" |
    tee -a "$summary"
  if "$bin" train compare --reference "$KIT/models/rigidformer-small/eval" --candidate "$sc" \
    >"$sc/compare.txt" 2>&1; then
    say "against the release (the card's ship rule):"
    tail -4 "$sc/compare.txt" | tee -a "$summary"
  else
    say "against the release: not compared ($(grep -m1 '^Error' "$sc/compare.txt"))"
  fi
fi

# --- results ---------------------------------------------------------------------------------
cp "$summary" "$work/results/summary.txt"
tar -czf "$out/results.tar.gz" -C "$work" results
for f in "$out"/*; do
  size=$(stat -c %s "$f")
  if [ "$size" -gt $((16 * 1024 * 1024)) ]; then
    echo "kit: $f is $size bytes, over 16 MiB" >&2
    failed=1
  fi
done
say "results: $(cd "$out" && ls | tr '\n' ' ')"
exit "$failed"
