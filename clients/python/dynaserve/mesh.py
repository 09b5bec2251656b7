"""Mesh scenes and sampled trajectories of PhysiFormer models (``generate``), numpy in and out,
shared by both transports.

A mesh scene lives in the model's closed box ``[-e, e]^3`` (``ModelInfo.box_half_extent``),
gravity along -z. Units: metres, seconds; vertices are given at frame 0 in the world frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np
import numpy.typing as npt

from .errors import DynaserveError
from .scene import array_arg, index_arg, velocity_doc

MATERIALS = ("rigid", "elastic")
SAMPLERS = ("heun", "euler")


@dataclass
class MeshObject:
    """One object of a mesh scene at frame 0.

    Attributes:
        vertices: ``[N, 3]`` vertex positions, metres, world frame. Required.
        material: ``"rigid"`` (keeps its shape) or ``"elastic"`` (deforms). Default
            ``"rigid"``.
        faces: optional ``[M, 3]`` vertex index triples (checked by the server, not used by
            the model; a trajectory keeps the vertex order, so they draw every frame).
            Default ``None``: no faces.
        velocity: optional ``[6]``: the vertex centroid's linear velocity (m/s) then the
            angular velocity about it (rad/s), world frame. Default ``None``: at rest.
        vertex_velocities: optional ``[N, 3]`` per-vertex initial velocities (m/s) instead of
            ``velocity`` (the official PhysiFormer data's form); give one or the other.
            Default ``None``.
    """

    vertices: npt.ArrayLike
    material: str = "rigid"
    faces: Optional[npt.ArrayLike] = None
    velocity: Optional[npt.ArrayLike] = None
    vertex_velocities: Optional[npt.ArrayLike] = None

    def checked(self, name: str = "object") -> "MeshObject":
        """This object with its arrays checked and converted to numpy (``faces`` ``int64``);
        a ``ValueError`` names ``name`` and the field otherwise."""
        if self.material not in MATERIALS:
            raise ValueError(f"{name}.material: {self.material!r} is not one of {sorted(MATERIALS)}")

        def opt(value: Any, field: str, shape: Tuple[Any, ...]) -> Optional[np.ndarray]:
            return None if value is None else array_arg(value, f"{name}.{field}", shape)

        return MeshObject(
            vertices=array_arg(self.vertices, f"{name}.vertices", ("N", 3)),
            material=self.material,
            faces=None if self.faces is None else index_arg(self.faces, f"{name}.faces"),
            velocity=opt(self.velocity, "velocity", (6,)),
            vertex_velocities=opt(self.vertex_velocities, "vertex_velocities", ("N", 3)),
        )

    def doc(self) -> Dict[str, Any]:
        """The JSON ``MeshObject`` document of a checked object (see :meth:`checked`)."""
        d: Dict[str, Any] = {"vertices": np.asarray(self.vertices).tolist(), "material": self.material}
        faces = np.asarray(self.faces if self.faces is not None else [])
        if faces.size:
            d["faces"] = faces.tolist()
        if self.velocity is not None:
            d["velocity"] = velocity_doc(self.velocity)
        if self.vertex_velocities is not None:
            d["vertex_velocities"] = np.asarray(self.vertex_velocities).tolist()
        return d


def checked_objects(objects: Sequence[MeshObject]) -> List[MeshObject]:
    """Every object checked (see :meth:`MeshObject.checked`; errors name ``objects[i]``)."""
    return [o.checked(f"objects[{i}]") for i, o in enumerate(objects)]


def check_sampler(sampler: str) -> str:
    """``sampler`` if it is one the server has, else a ``ValueError``."""
    if sampler not in SAMPLERS:
        raise ValueError(f"sampler: {sampler!r} is not one of {sorted(SAMPLERS)}")
    return sampler


@dataclass
class Generated:
    """The sampled trajectories of one Generate call.

    Attributes:
        vertices: ``[samples, frames, vertices, 3]``, metres, world frame: every object's
            vertices concatenated in request order (object ``j`` is
            ``vertices[:, :, offsets[j]:offsets[j + 1]]``).
        offsets: ``[objects + 1]`` start of each object's vertices in the vertex axis.
        poses: ``[samples, frames, objects, 7]`` rigid objects' Kabsch-fitted poses (body
            frame: the frame-0 vertices about their centroid, so frame 0 is the identity
            rotation); ``NaN`` rows for elastic objects.
        fit_rms: ``[samples, frames, objects]`` RMS distance (metres) of a rigid object's
            vertices from its fitted rigid motion; ``NaN`` for elastic objects.
        times: ``[frames]`` seconds since frame 0.
        seeds: ``[samples]`` seed of each sample's starting noise.
        model: the model that served the call.
        request_id: the server's request id.
        progress: one entry per denoising step: ``step``, ``steps``, ``t`` (flow time) and the
            server's ``queue_ms``, ``forward_ms`` and ``batch_scenes``.
    """

    vertices: np.ndarray
    offsets: np.ndarray
    poses: np.ndarray
    fit_rms: np.ndarray
    times: np.ndarray
    seeds: np.ndarray
    model: str
    request_id: str
    progress: List[dict]

    def object_vertices(self, j: int) -> np.ndarray:
        """Object ``j``'s vertices, ``[samples, frames, n_j, 3]``."""
        return self.vertices[:, :, self.offsets[j] : self.offsets[j + 1]]


ObjectFrame = Tuple[Any, Optional[np.ndarray], Optional[float]]
"""One object at one frame as either transport reads it: vertices (flat or ``[n, 3]``), the
fitted ``[7]`` pose (``None`` for an elastic object) and its fit RMS."""


class Collector:
    """Gathers the progress and sample events of one Generate call (over either transport)
    into a :class:`Generated`; ``objects`` are the checked objects of the request."""

    def __init__(self, objects: Sequence[MeshObject], on_progress: Optional[Callable[[dict], None]]) -> None:
        counts = [len(np.asarray(o.vertices)) for o in objects]
        self.offsets = np.concatenate([[0], np.cumsum(counts)]).astype(int)
        self.on_progress = on_progress
        self.progress: List[dict] = []
        self.samples: Dict[int, Tuple[int, List[Tuple[float, List[ObjectFrame]]]]] = {}

    def add_progress(self, d: dict) -> None:
        """One denoising step: ``step``, ``steps``, ``t``, ``queue_ms``, ``forward_ms``,
        ``batch_scenes``."""
        self.progress.append(d)
        if self.on_progress is not None:
            self.on_progress(d)

    def add_sample(self, index: int, seed: int, frames: List[Tuple[float, List[ObjectFrame]]]) -> None:
        """One sampled trajectory: per frame its time and every object's :data:`ObjectFrame`."""
        self.samples[int(index)] = (int(seed), frames)

    def result(self, model: str, request_id: str) -> Generated:
        order = [self.samples[k] for k in sorted(self.samples)]
        if not order:
            raise DynaserveError(500, "INTERNAL", "the Generate stream ended without a sample")
        n_obj, n_frames = len(self.offsets) - 1, len(order[0][1])
        verts = np.zeros((len(order), n_frames, int(self.offsets[-1]), 3))
        poses = np.full((len(order), n_frames, n_obj, 7), np.nan)
        rms = np.full((len(order), n_frames, n_obj), np.nan)
        for s, (_, frames) in enumerate(order):
            for f, (_, objects) in enumerate(frames):
                for j, (v, pose, fit) in enumerate(objects):
                    verts[s, f, self.offsets[j] : self.offsets[j + 1]] = np.asarray(v, dtype=float).reshape(-1, 3)
                    if pose is not None:
                        poses[s, f, j] = pose
                        rms[s, f, j] = np.nan if fit is None else fit
        return Generated(
            vertices=verts,
            offsets=self.offsets,
            poses=poses,
            fit_rms=rms,
            times=np.array([t for t, _ in order[0][1]], dtype=float),
            seeds=np.array([seed for seed, _ in order], dtype=np.uint64),
            model=model,
            request_id=request_id,
            progress=self.progress,
        )
