"""numpy arrays to and from the server's JSON documents.

Conventions (those of the server): metres, seconds, kilograms; z up, the ground plane's top at
z = 0; a pose is ``[x, y, z, qx, qy, qz, qw]`` (centre of mass in the world frame, then the
unit quaternion body-to-world, scalar last); point clouds are ``[n, 3]`` in the body frame with
the origin at the centre of mass.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Sequence

import numpy as np

IDENTITY = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])


def pose_doc(pose: Sequence[float]) -> Dict[str, List[float]]:
    """A ``[7]`` pose as the JSON ``Pose`` document."""
    p = np.asarray(pose, dtype=float).reshape(7)
    return {"translation": p[:3].tolist(), "rotation": p[3:].tolist()}


def pose_array(doc: Dict[str, Any]) -> np.ndarray:
    """A JSON ``Pose`` document as a ``[7]`` array."""
    return np.array(list(doc["translation"]) + list(doc.get("rotation", [0, 0, 0, 1])), dtype=float)


def poses_array(docs: Sequence[Dict[str, Any]]) -> np.ndarray:
    """A list of ``Pose`` documents as an ``[objects, 7]`` array."""
    return np.stack([pose_array(d) for d in docs]) if docs else np.zeros((0, 7))


def box_points(half_extents: Sequence[float], n: int = 96, seed: int = 0) -> np.ndarray:
    """``n`` points on the surface of a box with the given half extents (metres), ``[n, 3]``,
    body frame; faces sampled in proportion to their area."""
    h = np.asarray(half_extents, dtype=float)
    rng = np.random.default_rng(seed)
    areas = np.array([h[1] * h[2], h[0] * h[2], h[0] * h[1]] * 2)
    faces = rng.choice(6, size=n, p=areas / areas.sum())
    pts = rng.uniform(-1.0, 1.0, size=(n, 3)) * h
    axis = faces % 3
    sign = np.where(faces < 3, 1.0, -1.0)
    pts[np.arange(n), axis] = sign * h[axis]
    return pts


@dataclass
class Body:
    """One rigid object of a scene.

    Attributes:
        points: surface points ``[n, 3]``, metres, body frame (origin at the centre of mass).
        pose: current pose ``[7]``.
        velocity: optional ``[6]``: linear m/s then angular rad/s, world frame; ``None`` is at rest.
        mass: kilograms. friction: Coulomb coefficient. restitution: in [0, 1].
    """

    points: np.ndarray
    pose: np.ndarray = field(default_factory=lambda: IDENTITY.copy())
    velocity: Optional[np.ndarray] = None
    mass: float = 1.0
    friction: float = 0.5
    restitution: float = 0.2

    def doc(self) -> Dict[str, Any]:
        """The JSON ``ObjectSpec`` document."""
        d: Dict[str, Any] = {
            "points": np.asarray(self.points, dtype=float).reshape(-1, 3).tolist(),
            "pose": pose_doc(self.pose),
            "mass": float(self.mass),
            "friction": float(self.friction),
            "restitution": float(self.restitution),
        }
        if self.velocity is not None:
            v = np.asarray(self.velocity, dtype=float).reshape(6)
            d["velocity"] = {"linear": v[:3].tolist(), "angular": v[3:].tolist()}
        return d


def scene_doc(bodies: Sequence[Body]) -> Dict[str, Any]:
    """The JSON ``Scene`` document of some bodies."""
    return {"objects": [b.doc() for b in bodies]}


def object_state_doc(index: int, pose: Sequence[float], velocity: Optional[Sequence[float]] = None) -> Dict[str, Any]:
    """The JSON ``ObjectState`` document: object ``index`` at ``pose`` ``[7]`` with an optional
    velocity ``[6]`` (at rest without)."""
    d: Dict[str, Any] = {"object": int(index), "pose": pose_doc(pose)}
    if velocity is not None:
        v = np.asarray(velocity, dtype=float).reshape(6)
        d["velocity"] = {"linear": v[:3].tolist(), "angular": v[3:].tolist()}
    return d


def actions_doc(kinematic: Dict[int, np.ndarray]) -> List[Dict[str, Any]]:
    """Per-step actions from kinematic paths: ``{object index: [steps, 7] poses}`` (the pose
    of each kinematic object at the end of every step) as a list of ``Action`` documents."""
    if not kinematic:
        return []
    steps = {len(np.asarray(p).reshape(-1, 7)) for p in kinematic.values()}
    if len(steps) != 1:
        raise ValueError("every kinematic path needs the same number of steps")
    n = steps.pop()
    paths = {j: np.asarray(p, dtype=float).reshape(-1, 7) for j, p in kinematic.items()}
    return [
        {"kinematic": [{"object": int(j), "pose": pose_doc(p[k])} for j, p in paths.items()]}
        for k in range(n)
    ]
