"""Python client of Dynaserve, the learned-physics world-model server.

>>> from dynaserve import Client, Body, box_points
>>> c = Client("http://127.0.0.1:8080")
>>> s = c.create_session([Body(box_points([0.1, 0.1, 0.1]), pose=[0, 0, 0.1, 0, 0, 0, 1])])
>>> frames = s.step(10)          # frames[-1].poses is [objects, 7]

Points are in the body frame, centred at the centre of mass; ``Body.from_world_points(cloud)``
makes a body from a segmented world-frame cloud. The same calls over gRPC, with the closed
``interact`` loop, are in :mod:`dynaserve.grpc` (``pip install 'dynaserve[grpc]'``; not imported
here, so the HTTP client needs numpy only).
"""

import importlib.metadata as _metadata
import pathlib as _pathlib
import re as _re

from .client import AFFINITY_HEADER, AsyncClient, Client, Frame, PosesAndSpread, Session
from .errors import BodyFrameWarning, DynaserveError, OutOfRangeWarning
from .gradient import Gradients, gradient_cost
from .mesh import Generated, MeshObject
from .scene import Body, box_points, pose_array, pose_doc


def _version() -> str:
    """The installed distribution's version, else the one in the source tree's pyproject.toml."""
    try:
        return _metadata.version("dynaserve")
    except _metadata.PackageNotFoundError:
        pyproject = _pathlib.Path(__file__).resolve().parent.parent / "pyproject.toml"
        found = _re.search(r'^version = "([^"]+)"', pyproject.read_text(), _re.M) if pyproject.is_file() else None
        return found.group(1) if found else "0+unknown"


__version__ = _version()

__all__ = [
    "AFFINITY_HEADER",
    "AsyncClient",
    "Body",
    "BodyFrameWarning",
    "Client",
    "DynaserveError",
    "Frame",
    "Generated",
    "Gradients",
    "MeshObject",
    "OutOfRangeWarning",
    "PosesAndSpread",
    "Session",
    "__version__",
    "box_points",
    "gradient_cost",
    "pose_array",
    "pose_doc",
]
