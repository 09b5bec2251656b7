"""Python client of Dynaserve, the learned-physics world-model server.

>>> from dynaserve import Client, Body, box_points
>>> c = Client("http://127.0.0.1:8080")
>>> s = c.create_session([Body(box_points([0.1, 0.1, 0.1]), pose=[0, 0, 0.1, 0, 0, 0, 1])])
>>> frames = s.step(10)          # frames[-1].poses is [objects, 7]

The same calls over gRPC, with the closed ``interact`` loop and PhysiFormer ``generate``, are in
:mod:`dynaserve.grpc` (``pip install 'dynaserve[grpc]'``; not imported here, so the HTTP client
needs numpy only).
"""

from .client import AFFINITY_HEADER, AsyncClient, Client, Frame, Session
from .errors import DynaserveError, OutOfRangeWarning
from .mesh import Generated, MeshObject
from .scene import Body, box_points, pose_array, pose_doc

__all__ = [
    "AFFINITY_HEADER",
    "AsyncClient",
    "Body",
    "Client",
    "DynaserveError",
    "Frame",
    "Generated",
    "MeshObject",
    "OutOfRangeWarning",
    "Session",
    "box_points",
    "pose_array",
    "pose_doc",
]
