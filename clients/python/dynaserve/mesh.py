"""Mesh scenes and sampled trajectories of PhysiFormer models (``Generate``), numpy in and out.

A mesh scene lives in the model's closed box ``[-e, e]^3`` (``ModelInfo.box_half_extent``),
gravity along -z. Units: metres, seconds; vertices are given at frame 0 in the world frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional

import numpy as np


@dataclass
class MeshObject:
    """One object of a mesh scene at frame 0.

    Attributes:
        vertices: ``[n, 3]`` vertex positions, metres, world frame.
        material: ``"rigid"`` (keeps its shape) or ``"elastic"`` (deforms).
        faces: optional ``[m, 3]`` vertex index triples (checked by the server, not used by
            the model; a trajectory keeps the vertex order, so they draw every frame).
        velocity: optional ``[6]``: the vertex centroid's linear velocity (m/s) then the
            angular velocity about it (rad/s), world frame; ``None`` is at rest.
    """

    vertices: np.ndarray
    material: str = "rigid"
    faces: Optional[np.ndarray] = None
    velocity: Optional[np.ndarray] = None


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
