#!/usr/bin/env bash
# Installs what `cargo build --release --features cuda` needs (the CUDA compiler, headers and
# the libraries the binary links) from NVIDIA's wheels on the Python package index into a
# local folder: no system CUDA, no root. CUDA 13.0 (the first release whose wheels carry nvcc;
# it needs an NVIDIA driver of the 580 series or newer to run).
#
#   deploy/cuda/toolkit.sh [DEST]          # default DEST: target/cuda (about 2.3 GB)
#   source target/cuda/env.sh              # CUDA_HOME, PATH, CUDA_COMPUTE_CAP, library paths
#   cargo build --release --features cuda
#   target/cuda/run.sh target/release/dynaserve serve --device cuda
#
# No machine here has the NVIDIA driver, so the script also writes a stub `libcuda.so` (every
# driver entry point the build references, each answering CUDA_ERROR_STUB_LIBRARY) for the
# linker, as the toolkit's own `lib64/stubs` does. `run.sh` puts the toolkit's libraries on the
# library path, and the stub only where the machine has no driver: the binary then starts and
# refuses `--device cuda` with the driver's error instead of failing to load.
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/../.." && pwd)
DEST=$(mkdir -p "${1:-$ROOT/target/cuda}" && cd "${1:-$ROOT/target/cuda}" && pwd)
# Compute capability the kernels are compiled for (90: H100 and H200; 80: A100).
CAP=${CUDA_COMPUTE_CAP:-90}
WHEELS=(
  nvidia-cuda-nvcc==13.0.88 nvidia-nvvm==13.0.88 nvidia-cuda-crt==13.0.88
  nvidia-cuda-runtime==13.0.96 nvidia-cuda-cccl==13.0.85 nvidia-cuda-nvrtc==13.0.88
  "nvidia-cublas==13.0.*" nvidia-curand==10.4.0.35
)

echo "cuda toolkit: downloading ${#WHEELS[@]} wheels into $DEST/wheels"
python3 -m pip download --quiet --no-deps --only-binary=:all: -d "$DEST/wheels" "${WHEELS[@]}"

echo "cuda toolkit: unpacking"
python3 - "$DEST" <<'PY'
import pathlib, sys, zipfile, stat
dest = pathlib.Path(sys.argv[1])
for whl in sorted((dest / "wheels").glob("*.whl")):
    with zipfile.ZipFile(whl) as z:
        for info in z.infolist():
            parts = info.filename.split("/")
            # nvidia/cu13/{bin,include,lib,nvvm}/... -> DEST/{bin,include,lib64,nvvm}/...
            if len(parts) < 4 or parts[0] != "nvidia" or info.is_dir():
                continue
            rel = parts[2:]
            if rel[0] == "lib":
                rel[0] = "lib64"
            out = dest.joinpath(*rel)
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_bytes(z.read(info))
            if rel[0] in ("bin", "nvvm") or ".so" in rel[-1]:
                out.chmod(out.stat().st_mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)
PY

# Unversioned names for the linker (libcublas.so -> libcublas.so.13, ...).
for lib in "$DEST"/lib64/lib*.so.*; do
  base=${lib%%.so.*}.so
  [ -e "$base" ] || ln -s "$(basename "$lib")" "$base"
done

echo "cuda toolkit: the driver stub"
mkdir -p "$DEST/lib64/stubs"
CUDARC=$(ls -d "${CARGO_HOME:-$HOME/.cargo}"/registry/src/*/cudarc-0.19.* 2>/dev/null | tail -1 || true)
if [ -z "$CUDARC" ]; then
  (cd "$ROOT" && cargo fetch --quiet)
  CUDARC=$(ls -d "${CARGO_HOME:-$HOME/.cargo}"/registry/src/*/cudarc-0.19.* | tail -1)
fi
grep -o 'fn cu[A-Za-z0-9_]*(' "$CUDARC/src/driver/sys/mod.rs" | sed 's/^fn //; s/($//' | sort -u |
  awk '{ printf "int %s(void) { return 34; }\n", $1 }' > "$DEST/lib64/stubs/cuda_stub.c"
cc -shared -fPIC -Wl,-soname,libcuda.so.1 -o "$DEST/lib64/stubs/libcuda.so" "$DEST/lib64/stubs/cuda_stub.c"
ln -sf libcuda.so "$DEST/lib64/stubs/libcuda.so.1"

cat > "$DEST/env.sh" <<ENV
# Source this before \`cargo build --features cuda\`.
export CUDA_HOME="$DEST" CUDA_PATH="$DEST" CUDA_ROOT="$DEST"
export PATH="$DEST/bin:\$PATH"
export CUDA_COMPUTE_CAP=\${CUDA_COMPUTE_CAP:-$CAP}
export LIBRARY_PATH="$DEST/lib64:$DEST/lib64/stubs\${LIBRARY_PATH:+:\$LIBRARY_PATH}"
export NVCC_PREPEND_FLAGS="-I$DEST/include/cccl \${NVCC_PREPEND_FLAGS:-}"
ENV

cat > "$DEST/run.sh" <<RUN
#!/usr/bin/env bash
# Runs a cuda build with the toolkit's libraries; with the driver stub where there is no driver.
libs="$DEST/lib64"
if ! ldconfig -p 2>/dev/null | grep -q 'libcuda\.so\.1 '; then libs="\$libs:$DEST/lib64/stubs"; fi
export LD_LIBRARY_PATH="\$libs\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}"
exec "\$@"
RUN
chmod +x "$DEST/run.sh"
"$DEST/bin/nvcc" --version | tail -2
echo "cuda toolkit: done; source $DEST/env.sh, then cargo build --release --features cuda"
