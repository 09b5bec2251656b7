#!/usr/bin/env bash
# Assembles the GPU kit (deploy/gpu-kit/README.md): a folder of at most 60 MiB that runs on a
# Linux machine with an NVIDIA driver but no Rust, no CUDA toolkit and no network.
#
#   deploy/gpu-kit/pack.sh [--binary PATH] [--out DIR] [--link]
#
# --binary: the dynaserve to ship (default target/cuda-build/release/dynaserve, which
#   deploy/cuda/build.sh builds); stripped and xz-compressed into the kit.
# --out: the kit folder (default target/gpu-kit), replaced.
# --link: link the binary instead of compressing it (a local check of the kit, as CI runs it).
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
binary="$ROOT/target/cuda-build/release/dynaserve" out="$ROOT/target/gpu-kit" link=0
while [ $# -gt 0 ]; do
  case "$1" in
    --binary) binary=$2; shift 2 ;;
    --out) out=$2; shift 2 ;;
    --link) link=1; shift ;;
    *) echo "pack: unknown argument $1" >&2; exit 2 ;;
  esac
done
[ -x "$binary" ] || { echo "pack: no binary at $binary (build it with deploy/cuda/build.sh)" >&2; exit 2; }
binary=$(cd "$(dirname "$binary")" && pwd)/$(basename "$binary")
rm -rf "$out"
mkdir -p "$out"/{configs,recipes,lib,models/rigidformer-small/eval,models/physiformer-small}
cp "$ROOT/deploy/gpu-kit/kit.sh" "$ROOT/deploy/gpu-kit/README.md" "$out/"
cp -r "$ROOT"/crates/train/configs/. "$out/configs/"
cp "$ROOT"/deploy/gpu-kit/configs/*.toml "$out/configs/"
cp "$ROOT"/deploy/gpu-kit/recipes/*.txt "$out/recipes/"
for m in rigidformer-small physiformer-small; do
  cp "$ROOT/models/$m/config.json" "$ROOT/models/$m/model.safetensors" "$out/models/$m/"
done
cp "$ROOT"/models/rigidformer-small/eval/{eval,fresh,physics-suite}.json "$out/models/rigidformer-small/eval/"
# The chart libraries (fontconfig, freetype and theirs) for a machine without them; the kit
# uses them only when the system's are missing.
ldd "$binary" | awk '/=> \// { print $3 }' |
  grep -E 'lib(fontconfig|freetype|expat|png16|brotlidec|brotlicommon|z)\.so' |
  while read -r lib; do cp -L "$lib" "$out/lib/"; done
if [ "$link" = 1 ]; then
  ln -s "$binary" "$out/dynaserve"
else
  tmp=$(mktemp)
  trap 'rm -f "$tmp"' EXIT
  strip -o "$tmp" "$binary"
  xz -6 -T0 -c "$tmp" >"$out/dynaserve.xz"
fi
size=$(du -sb "$out" | cut -f1)
echo "gpu kit: $out, $((size / 1024 / 1024)) MiB ($(cd "$out" && ls | tr '\n' ' '))"
if [ "$size" -gt $((60 * 1024 * 1024)) ]; then
  echo "pack: the kit is over 60 MiB" >&2
  exit 1
fi
