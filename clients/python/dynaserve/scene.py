"""numpy arrays to and from the server's JSON documents, and the checks of array arguments.

Conventions (those of the server): metres, seconds, kilograms; z up, the ground plane's top at
z = 0; a pose is ``[x, y, z, qx, qy, qz, qw]`` (centre of mass in the world frame, then the
unit quaternion body-to-world, scalar last); point clouds are ``[N, 3]`` in the body frame with
the origin at the centre of mass (:meth:`Body.from_world_points` makes such a body from a
world-frame cloud).
"""

from __future__ import annotations

import reprlib
import warnings
from dataclasses import dataclass, field
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

from .errors import BodyFrameWarning

IDENTITY = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])

Shape = Tuple[Union[int, str], ...]


def array_arg(value: Any, name: str, shape: Shape) -> np.ndarray:
    """``value`` as a float array of ``shape`` (a ``str`` entry, e.g. ``"N"``, is any length;
    ``()`` a scalar) with every value finite; otherwise a ``ValueError`` naming the argument,
    e.g. ``bodies[0].points: expected [N, 3], got shape (3, 5)``."""
    want = "a number" if shape == () else "[" + ", ".join(str(n) for n in shape) + "]"
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected {want}, got {reprlib.repr(value)}") from None
    if a.ndim != len(shape) or any(isinstance(n, int) and n != m for n, m in zip(shape, a.shape)):
        raise ValueError(f"{name}: expected {want}, got shape {a.shape}")
    bad = np.argwhere(~np.isfinite(a))
    if len(bad):
        at = "" if shape == () else f" at {bad[0].tolist()}"
        raise ValueError(f"{name}: {a[tuple(bad[0])]}{at} is not finite")
    return a


def index_arg(value: Any, name: str) -> np.ndarray:
    """Triangles ``[M, 3]`` of vertex indices (non-negative integers), as ``int64``; an empty
    list is no triangles."""
    if hasattr(value, "__len__") and len(value) == 0:
        return np.zeros((0, 3), dtype=np.int64)
    a = array_arg(value, name, ("M", 3))
    bad = np.argwhere((a != np.round(a)) | (a < 0))
    if len(bad):
        raise ValueError(f"{name}: {a[tuple(bad[0])]:g} at {bad[0].tolist()} is not a vertex index")
    return a.astype(np.int64)


def number(value: Any, name: str) -> float:
    """A finite number, or a ``ValueError`` naming the argument."""
    return float(array_arg(value, name, ()))


def velocity_doc(v: npt.ArrayLike, name: str = "velocity") -> Dict[str, List[float]]:
    """A ``[6]`` velocity (linear m/s, then angular rad/s) as the JSON ``Velocity`` document."""
    a = array_arg(v, name, (6,))
    return {"linear": a[:3].tolist(), "angular": a[3:].tolist()}


def pose_doc(pose: npt.ArrayLike, name: str = "pose") -> Dict[str, List[float]]:
    """A ``[7]`` pose as the JSON ``Pose`` document."""
    p = array_arg(pose, name, (7,))
    return {"translation": p[:3].tolist(), "rotation": p[3:].tolist()}


def pose_array(doc: Mapping[str, Any]) -> np.ndarray:
    """A JSON ``Pose`` document as a ``[7]`` array."""
    return np.array(list(doc["translation"]) + list(doc.get("rotation", [0, 0, 0, 1])), dtype=float)


def poses_array(docs: Sequence[Mapping[str, Any]]) -> np.ndarray:
    """A list of ``Pose`` documents as an ``[objects, 7]`` array."""
    return np.stack([pose_array(d) for d in docs]) if docs else np.zeros((0, 7))


def box_points(half_extents: npt.ArrayLike, n: int = 96, seed: int = 0) -> np.ndarray:
    """``n`` points on the surface of a box with the given ``[3]`` half extents (metres),
    ``[n, 3]``, body frame; faces sampled in proportion to their area."""
    h = array_arg(half_extents, "half_extents", (3,))
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

    Every parameter is sent explicitly, so the server's own defaults for an object document
    (friction and restitution 0 when absent, mass required) never apply to a ``Body``.

    Attributes:
        points: surface points ``[N, 3]``, metres, in the body frame: the origin at the centre
            of mass, the axes those of ``pose``. Required. A segmented world-frame cloud goes
            through :meth:`from_world_points`; points whose centroid lies far from the origin
            raise a :class:`~dynaserve.BodyFrameWarning`.
        pose: current pose ``[7]`` ``[x, y, z, qx, qy, qz, qw]`` (metres; unit quaternion
            body to world). Default: the identity, ``[0, 0, 0, 0, 0, 0, 1]``.
        velocity: optional ``[6]``: linear m/s then angular rad/s, world frame. Default
            ``None``: at rest.
        mass: kilograms, in (0, 1e4]. Default 1.0 (a RigidFormer sees only the mass ratios
            within a scene).
        friction: Coulomb coefficient, in [0, 10]. Default 0.5 (inside the shipped model's
            trained 0.1-1.0).
        restitution: coefficient of restitution, in [0, 1]. Default 0.2 (inside the shipped
            model's trained 0.05-0.8).
    """

    points: npt.ArrayLike
    pose: npt.ArrayLike = field(default_factory=lambda: IDENTITY.copy())
    velocity: Optional[npt.ArrayLike] = None
    mass: float = 1.0
    friction: float = 0.5
    restitution: float = 0.2

    def __post_init__(self) -> None:
        try:
            p = array_arg(self.points, "points", ("N", 3))
        except ValueError:
            return  # refused, naming the body, when it is sent
        if len(p) == 0:
            return
        offset = float(np.linalg.norm(p.mean(axis=0)))
        extent = float((p.max(axis=0) - p.min(axis=0)).max())
        if offset > 0.1 * extent and offset > 0.01:
            warnings.warn(
                f"Body points: their centroid lies {offset:.3g} m from the body-frame origin "
                f"(the cloud spans {extent:.3g} m); points are in the body frame, centred at the "
                "centre of mass. For a world-frame cloud use Body.from_world_points(points, ...).",
                BodyFrameWarning,
                stacklevel=3,
            )

    @classmethod
    def from_world_points(cls, points: npt.ArrayLike, **kwargs: Any) -> "Body":
        """A body from a segmented world-frame cloud ``[N, 3]`` (metres): its pose is the
        cloud's centroid with the identity rotation, its points the cloud minus the centroid
        (the centroid stands in for the centre of mass). Other arguments (``velocity``,
        ``mass``, ``friction``, ``restitution``) go to :class:`Body` as given."""
        p = array_arg(points, "points", ("N", 3))
        c = p.mean(axis=0)
        return cls(p - c, pose=np.concatenate([c, IDENTITY[3:]]), **kwargs)

    def doc(self, name: str = "body") -> Dict[str, Any]:
        """The JSON ``ObjectSpec`` document; a ``ValueError`` names ``name`` and the field of
        an array of the wrong shape or a value that is not finite."""
        d: Dict[str, Any] = {
            "points": array_arg(self.points, f"{name}.points", ("N", 3)).tolist(),
            "pose": pose_doc(self.pose, f"{name}.pose"),
            "mass": number(self.mass, f"{name}.mass"),
            "friction": number(self.friction, f"{name}.friction"),
            "restitution": number(self.restitution, f"{name}.restitution"),
        }
        if self.velocity is not None:
            d["velocity"] = velocity_doc(self.velocity, f"{name}.velocity")
        return d


def scene_doc(bodies: Sequence[Body], name: str = "bodies") -> Dict[str, Any]:
    """The JSON ``Scene`` document of some bodies (errors name ``bodies[i]``)."""
    return {"objects": [b.doc(f"{name}[{i}]") for i, b in enumerate(bodies)]}


def object_state_doc(
    index: int,
    pose: npt.ArrayLike,
    velocity: Optional[npt.ArrayLike] = None,
    names: Tuple[str, str] = ("poses", "velocities"),
) -> Dict[str, Any]:
    """The JSON ``ObjectState`` document: object ``index`` at ``pose`` ``[7]`` with an optional
    velocity ``[6]`` (at rest without); errors name ``poses[index]`` / ``velocities[index]``
    (the prefixes ``names``)."""
    d: Dict[str, Any] = {"object": int(index), "pose": pose_doc(pose, f"{names[0]}[{index}]")}
    if velocity is not None:
        d["velocity"] = velocity_doc(velocity, f"{names[1]}[{index}]")
    return d


def kinematic_paths(kinematic: Mapping[int, npt.ArrayLike], name: str = "kinematic") -> Tuple[int, Dict[int, np.ndarray]]:
    """Checked kinematic paths ``{object index: [steps, 7] poses}`` and their common number of
    steps (0 for none)."""
    paths = {int(j): array_arg(p, f"{name}[{j}]", ("steps", 7)) for j, p in kinematic.items()}
    steps = {len(p) for p in paths.values()}
    if len(steps) > 1:
        raise ValueError(f"{name}: every kinematic path needs the same number of steps, got {sorted(steps)}")
    return (steps.pop() if steps else 0), paths


def actions_doc(kinematic: Mapping[int, npt.ArrayLike], name: str = "kinematic") -> List[Dict[str, Any]]:
    """Per-step actions from kinematic paths: ``{object index: [steps, 7] poses}`` (the pose
    of each kinematic object at the end of every step) as a list of ``Action`` documents."""
    n, paths = kinematic_paths(kinematic, name)
    return [
        {"kinematic": [{"object": j, "pose": pose_doc(p[k])} for j, p in paths.items()]}
        for k in range(n)
    ]
