"""Generates the gRPC stubs of ``dynaserve.v1`` from the repository's ``proto/`` directory.

    pip install 'grpcio-tools==1.85.1'    # the version the committed stubs were made with
    python clients/python/generate_stubs.py            # rewrites clients/python/dynaserve/v1/
    python clients/python/generate_stubs.py --out DIR  # writes DIR/dynaserve/v1/ instead

The proto package ``dynaserve.v1`` becomes the Python package ``dynaserve.v1``, so the stubs
import each other as ``dynaserve.v1.*`` inside this client. ``tests/test_stubs.py`` regenerates
them into a temporary directory and fails when they differ from the committed ones.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
from typing import List

HERE = pathlib.Path(__file__).resolve().parent
PROTO_ROOT = HERE.parent.parent / "proto"
PROTOS = ["dynaserve/v1/world_model.proto", "dynaserve/v1/sessions.proto"]
GRPC_TOOLS_VERSION = "1.85.1"
"""The grpcio-tools release the committed stubs were generated with."""


def generate(out: pathlib.Path) -> List[pathlib.Path]:
    """Writes ``*_pb2.py``, ``*_pb2.pyi`` and ``*_pb2_grpc.py`` of every proto file under
    ``out/dynaserve/v1/`` and returns their paths (sorted)."""
    from grpc_tools import protoc  # type: ignore[import-untyped]

    out.mkdir(parents=True, exist_ok=True)
    args = [
        "grpc_tools.protoc",
        f"-I{PROTO_ROOT}",
        f"--python_out={out}",
        f"--pyi_out={out}",
        f"--grpc_python_out={out}",
        *[str(PROTO_ROOT / p) for p in PROTOS],
    ]
    if protoc.main(args) != 0:
        raise RuntimeError(f"protoc failed: {' '.join(args)}")
    return sorted((out / "dynaserve" / "v1").glob("*_pb2*.py*"))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=pathlib.Path, default=HERE, help="root of the generated package tree")
    args = p.parse_args()
    for path in generate(args.out):
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
