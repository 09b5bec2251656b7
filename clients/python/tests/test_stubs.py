"""The committed gRPC stubs (`dynaserve/v1/`) are what `generate_stubs.py` makes from the
repository's `proto/` today: regenerated into a temporary directory, every file must be equal,
so a change of the .proto files without new stubs fails here. Needs the `stubs` extra
(grpcio-tools at the pinned release)."""

import importlib.metadata
import importlib.util
import pathlib
import re
import tempfile
import unittest

PACKAGE_ROOT = pathlib.Path(__file__).resolve().parent.parent
COMMITTED = PACKAGE_ROOT / "dynaserve" / "v1"


def load_generator():
    spec = importlib.util.spec_from_file_location("generate_stubs", PACKAGE_ROOT / "generate_stubs.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class StubsTest(unittest.TestCase):
    def test_committed_stubs_equal_freshly_generated_ones(self):
        gen = load_generator()
        # The generator release is the pinned one (its output differs between releases).
        self.assertEqual(importlib.metadata.version("grpcio-tools"), gen.GRPC_TOOLS_VERSION)
        pyproject = (PACKAGE_ROOT / "pyproject.toml").read_text()
        self.assertIn(f'"grpcio-tools=={gen.GRPC_TOOLS_VERSION}"', pyproject)
        self.assertIn(f'"grpcio>={gen.GRPC_TOOLS_VERSION}"', pyproject)
        with tempfile.TemporaryDirectory() as tmp:
            fresh = gen.generate(pathlib.Path(tmp))
            names = sorted(p.name for p in fresh)
            self.assertEqual(len(names), 6, names)
            self.assertEqual(names, sorted(p.name for p in COMMITTED.glob("*_pb2*.py*")))
            for p in fresh:
                self.assertEqual(
                    p.read_text(),
                    (COMMITTED / p.name).read_text(),
                    f"dynaserve/v1/{p.name} is stale: run python clients/python/generate_stubs.py",
                )
        # Every proto service has its stub.
        protos = "".join((gen.PROTO_ROOT / p).read_text() for p in gen.PROTOS)
        for service in re.findall(r"^service (\w+)", protos, re.M):
            self.assertIn(f"class {service}Stub", "".join(p.read_text() for p in COMMITTED.glob("*_grpc.py")))


if __name__ == "__main__":
    unittest.main()
