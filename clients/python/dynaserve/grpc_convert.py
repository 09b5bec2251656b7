"""Conversions of the gRPC client (:mod:`dynaserve.grpc`): numpy arrays, bodies and the HTTP
API's JSON documents to and from ``dynaserve.v1`` protobuf messages, the mapping of a failed
call to :class:`~dynaserve.errors.DynaserveError`, the request builders the synchronous and
asyncio clients share, and the parsing of a client's target.

The public converters (``pose_pb``, ``scene_pb``, ``action_pb``, ``frame_of``, ``model_info``,
``error_of``, ...) are re-exported by :mod:`dynaserve.grpc`; import them from there.
"""

from __future__ import annotations

import json
from typing import (
    Any,
    Dict,
    Iterable,
    List,
    Mapping,
    Optional,
    Sequence,
    Tuple,
    Union,
)

import numpy as np
import numpy.typing as npt
from google.rpc import error_details_pb2, status_pb2

from .client import Frame, predict_arrays, spread_array
from .errors import DynaserveError
from .gradient import Gradients, candidates_doc, cost_arg, gradients_of
from .mesh import Collector, MeshObject, check_sampler, checked_objects
from .scene import Body, array_arg, index_arg, kinematic_paths, number
from .v1 import sessions_pb2 as spb
from .v1 import world_model_pb2 as pb

DETAILS_KEY = "grpc-status-details-bin"
"""Trailer carrying the ``google.rpc.Status`` with the field of an invalid request."""
PUSHBACK_KEY = "grpc-retry-pushback-ms"
"""Trailer carrying the retry hint of an overloaded server, milliseconds."""
SESSION_KEY = "x-dynaserve-session"
"""Response header of Interact: the id of the session the stream drives."""

# The HTTP status the server gives each gRPC code (so ``DynaserveError.status`` means the same
# over both transports).
_HTTP_STATUS = {
    "INVALID_ARGUMENT": 422,
    "OUT_OF_RANGE": 422,
    "FAILED_PRECONDITION": 400,
    "NOT_FOUND": 404,
    "RESOURCE_EXHAUSTED": 429,
    "DEADLINE_EXCEEDED": 504,
    "UNAVAILABLE": 503,
    "CANCELLED": 499,
    "UNAUTHENTICATED": 401,
}

_MATERIALS = {"rigid": pb.MATERIAL_RIGID, "elastic": pb.MATERIAL_ELASTIC}
_SAMPLERS = {"heun": pb.SAMPLER_HEUN, "euler": pb.SAMPLER_EULER}

Scene = Union[Sequence[Body], Mapping[str, Any], pb.Scene]
"""A rigid scene: bodies, the HTTP API's ``Scene`` JSON document, or a ``dynaserve.v1.Scene``."""
Metadata = List[Tuple[str, str]]


# ---- errors ----


def _pairs(md: Any) -> Iterable[Tuple[str, Any]]:
    for item in md or ():
        yield item[0], item[1]


def _field_of(details: bytes) -> Optional[str]:
    """The first field violation of a serialized ``google.rpc.Status``, if any."""
    try:
        status = status_pb2.Status.FromString(details)
    except Exception:  # a malformed detail must not hide the error itself
        return None
    for any_detail in status.details:
        if any_detail.Is(error_details_pb2.BadRequest.DESCRIPTOR):
            bad = error_details_pb2.BadRequest()
            any_detail.Unpack(bad)
            if bad.field_violations:
                return bad.field_violations[0].field
    return None


def error_of(e: Any) -> DynaserveError:
    """The :class:`DynaserveError` of a failed call (a ``grpc.RpcError`` or
    ``grpc.aio.AioRpcError``): code name, HTTP-equivalent status, message, field path from
    the status details, retry hint from the ``grpc-retry-pushback-ms`` trailer."""
    code = e.code()
    name = code.name if code is not None else "UNKNOWN"
    field = None
    retry = None
    for key, value in _pairs(e.trailing_metadata()):
        if key == DETAILS_KEY and isinstance(value, bytes):
            field = _field_of(value)
        elif key == PUSHBACK_KEY:
            try:
                retry = int(value)
            except (TypeError, ValueError):
                pass
    return DynaserveError(_HTTP_STATUS.get(name, 500), name, e.details() or "", field, retry)


def _deadline(what: str, seconds: float) -> DynaserveError:
    return DynaserveError(504, "DEADLINE_EXCEEDED", f"{what}: no answer within {seconds} s")


# ---- numpy <-> messages ----


def pose_pb(pose: npt.ArrayLike, name: str = "pose") -> pb.Pose:
    """A ``[7]`` pose as a ``Pose`` message (a ``ValueError`` names ``name`` otherwise)."""
    p = array_arg(pose, name, (7,))
    return pb.Pose(
        translation=pb.Vec3(x=p[0], y=p[1], z=p[2]),
        rotation=pb.Quaternion(x=p[3], y=p[4], z=p[5], w=p[6]),
    )


def pose_np(p: pb.Pose) -> np.ndarray:
    """A ``Pose`` message as a ``[7]`` array (identity rotation when unset)."""
    t = p.translation
    if p.HasField("rotation"):
        r = p.rotation
        return np.array([t.x, t.y, t.z, r.x, r.y, r.z, r.w], dtype=float)
    return np.array([t.x, t.y, t.z, 0.0, 0.0, 0.0, 1.0])


def poses_np(poses: Sequence[pb.Pose]) -> np.ndarray:
    """``Pose`` messages as an ``[objects, 7]`` array."""
    return np.stack([pose_np(p) for p in poses]) if len(poses) else np.zeros((0, 7))


def _velocity(v: npt.ArrayLike, name: str = "velocity") -> pb.Velocity:
    a = array_arg(v, name, (6,))
    return pb.Velocity(linear=pb.Vec3(x=a[0], y=a[1], z=a[2]), angular=pb.Vec3(x=a[3], y=a[4], z=a[5]))


def object_spec(b: Body, name: str = "body") -> pb.ObjectSpec:
    """A :class:`Body` as an ``ObjectSpec`` message (its points as the reference cloud); a
    ``ValueError`` names ``name`` and the field of an array of the wrong shape or a value that
    is not finite."""
    o = pb.ObjectSpec(
        points=pb.PointCloud(xyz=array_arg(b.points, f"{name}.points", ("N", 3)).reshape(-1).tolist()),
        pose=pose_pb(b.pose, f"{name}.pose"),
        mass=number(b.mass, f"{name}.mass"),
        friction=number(b.friction, f"{name}.friction"),
        restitution=number(b.restitution, f"{name}.restitution"),
    )
    if b.velocity is not None:
        o.velocity.CopyFrom(_velocity(b.velocity, f"{name}.velocity"))
    return o


def _pose_doc_pb(d: Mapping[str, Any], name: str) -> pb.Pose:
    return pose_pb(list(d["translation"]) + list(d.get("rotation", [0.0, 0.0, 0.0, 1.0])), name)


def object_doc_pb(d: Mapping[str, Any], name: str = "object") -> pb.ObjectSpec:
    """An ``ObjectSpec`` JSON document of the HTTP API (``points`` ``[[x, y, z], ...]`` or a
    ``mesh``; ``pose``; ``velocity`` or ``previous_pose``; ``mass``, ``friction``,
    ``restitution``) as an ``ObjectSpec`` message, read as the server reads the document over
    HTTP: ``mass`` is required, an absent ``friction`` or ``restitution`` is 0. A missing or
    unknown key raises ``KeyError``, a bad value ``ValueError``, naming ``name`` and the key."""
    known = {"points", "mesh", "pose", "previous_pose", "velocity", "mass", "friction", "restitution"}
    unknown = set(d) - known
    if unknown:
        raise KeyError(f"{name}: unknown keys {sorted(unknown)}; expected some of {sorted(known)}")
    for key in ("pose", "mass"):
        if key not in d:
            raise KeyError(f"{name}.{key}: required")
    o = pb.ObjectSpec(
        pose=_pose_doc_pb(d["pose"], f"{name}.pose"),
        mass=number(d["mass"], f"{name}.mass"),
        friction=number(d.get("friction", 0.0), f"{name}.friction"),
        restitution=number(d.get("restitution", 0.0), f"{name}.restitution"),
    )
    if "points" in d:
        xyz = array_arg(d["points"], f"{name}.points", ("N", 3)).reshape(-1).tolist()
        o.points.CopyFrom(pb.PointCloud(xyz=xyz))
    if "mesh" in d:
        m = d["mesh"]
        o.mesh.CopyFrom(
            pb.TriangleMesh(
                vertices=array_arg(m["vertices"], f"{name}.mesh.vertices", ("N", 3)).reshape(-1).tolist(),
                faces=index_arg(m.get("faces", []), f"{name}.mesh.faces").reshape(-1).tolist(),
                samples=int(m.get("samples", 0)),
                seed=int(m.get("seed", 0)),
            )
        )
    if "velocity" in d:
        v = d["velocity"]
        o.velocity.CopyFrom(
            _velocity(list(v.get("linear", [0.0] * 3)) + list(v.get("angular", [0.0] * 3)), f"{name}.velocity")
        )
    if "previous_pose" in d:
        o.previous_pose.CopyFrom(_pose_doc_pb(d["previous_pose"], f"{name}.previous_pose"))
    return o


def scene_pb(scene: Scene, variant: Optional[int] = None) -> pb.Scene:
    """Bodies, a ``Scene`` JSON document of the HTTP API (e.g. the ``scene`` of a file in
    ``examples/scenes/``) or a ready ``Scene`` message, as a ``Scene`` message. Errors name
    ``bodies[i]`` or ``scene.objects[i]`` (``variants[k][i]`` or ``variants[k].objects[i]``
    for the ``variant`` ``k`` of a Predict call)."""
    if isinstance(scene, pb.Scene):
        return scene
    if isinstance(scene, Mapping):
        at = "scene" if variant is None else f"variants[{variant}]"
        return pb.Scene(objects=[object_doc_pb(o, f"{at}.objects[{i}]") for i, o in enumerate(scene["objects"])])
    at = "bodies" if variant is None else f"variants[{variant}]"
    return pb.Scene(objects=[object_spec(b, f"{at}[{i}]") for i, b in enumerate(scene)])


def action_pb(kinematic: Optional[Mapping[int, npt.ArrayLike]], name: str = "kinematic") -> spb.Action:
    """One step's action: ``{object index: [7] pose at the end of the step}``."""
    return spb.Action(
        kinematic=[
            spb.ObjectPose(object=int(j), pose=pose_pb(p, f"{name}[{j}]")) for j, p in (kinematic or {}).items()
        ]
    )


def actions_pb(kinematic: Optional[Mapping[int, npt.ArrayLike]], name: str = "kinematic") -> List[spb.Action]:
    """Per-step actions from kinematic paths ``{object index: [steps, 7] poses}``."""
    n, paths = kinematic_paths(kinematic or {}, name)
    return [action_pb({j: p[k] for j, p in paths.items()}) for k in range(n)]


def object_state_pb(
    index: int,
    pose: npt.ArrayLike,
    velocity: Optional[npt.ArrayLike] = None,
    names: Tuple[str, str] = ("poses", "velocities"),
) -> spb.ObjectState:
    """Object ``index`` at ``pose`` ``[7]``, at rest or with ``velocity`` ``[6]`` (linear m/s,
    angular rad/s, world frame); errors name ``poses[index]`` / ``velocities[index]`` (the
    prefixes ``names``)."""
    s = spb.ObjectState(object=int(index), pose=pose_pb(pose, f"{names[0]}[{index}]"))
    if velocity is not None:
        s.velocity.CopyFrom(_velocity(velocity, f"{names[1]}[{index}]"))
    return s


def _states(
    poses: Optional[Mapping[int, npt.ArrayLike]],
    velocities: Optional[Mapping[int, npt.ArrayLike]] = None,
    names: Tuple[str, str] = ("poses", "velocities"),
) -> List[spb.ObjectState]:
    velocities = velocities or {}
    return [object_state_pb(j, p, velocities.get(j), names) for j, p in (poses or {}).items()]


def frame_of(f: pb.StepFrame) -> Frame:
    """A ``StepFrame`` message as a :class:`Frame` (``poses`` ``[objects, 7]``, ``spread``
    ``[objects, 2]`` or ``None``)."""
    return Frame(step=int(f.step), time=float(f.time), poses=poses_np(f.poses), spread=spread_array(f.spread))


def _trajectories(resp: pb.PredictResponse, with_spread: bool = False) -> Any:
    """A ``PredictResponse``'s poses ``[variants, frames, objects, 7]``, or with
    ``with_spread`` ``(poses, spread)``: see :func:`dynaserve.client.predict_arrays`."""
    return predict_arrays(
        [[(poses_np(f.poses), spread_array(f.spread)) for f in t.frames] for t in resp.trajectories],
        with_spread,
    )


def _state(s: spb.SessionState) -> Dict[str, Any]:
    return {
        "step": int(s.step),
        "time": float(s.time),
        "poses": poses_np(s.poses),
        "previous_poses": poses_np(s.previous_poses),
        "expires_at_unix_ms": int(s.expires_at_unix_ms),
    }


def _f32(x: float) -> float:
    # The shortest decimal of a float32, as the HTTP API's JSON writes it.
    return float(str(np.float32(x)))


def model_info(m: pb.ModelInfo) -> Dict[str, Any]:
    """A ``ModelInfo`` message as the HTTP API's ``ModelInfo`` document (``gravity`` a ``[3]``
    list, ``config`` the parsed ``config.json``; PhysiFormer limits and an ensemble's
    ``members`` only when set)."""
    d: Dict[str, Any] = {
        "name": m.name,
        "architecture": m.architecture,
        "dt_frame": m.dt_frame,
        "default_points": m.default_points,
        "max_objects": m.max_objects,
        "max_points_per_object": m.max_points_per_object,
        "max_steps": m.max_steps,
        "max_dt_steps": m.max_dt_steps,
        "max_variants": m.max_variants,
        "max_request_cost": m.max_request_cost,
        "gravity": [_f32(m.gravity.x), _f32(m.gravity.y), _f32(m.gravity.z)],
        "config": json.loads(m.config_json) if m.config_json else {},
    }
    for key in ("max_vertices", "max_frames", "max_denoise_steps", "default_denoise_steps", "max_samples"):
        if getattr(m, key):
            d[key] = int(getattr(m, key))
    if m.box_half_extent:
        d["box_half_extent"] = _f32(m.box_half_extent)
    if m.members:
        d["members"] = list(m.members)
    d["gradients"] = bool(m.gradients)
    if m.max_gradient_work:
        d["max_gradient_work"] = int(m.max_gradient_work)
    return d


def _gradient_request(
    session_id: str,
    steps: int,
    kinematic: Sequence[Mapping[int, npt.ArrayLike]],
    cost: Any,
    every: int,
    timeout_ms: int,
) -> spb.SessionGradientRequest:
    """A session ``Gradient`` request: candidate paths ``[{index: [steps, 7]}]`` and a cost
    as the HTTP client takes them (see :meth:`dynaserve.Session.gradient`)."""
    candidates = [
        spb.GradientCandidate(
            actions=[
                spb.Action(kinematic=[spb.ObjectPose(object=k["object"], pose=_pose_doc_pb(k["pose"], "pose")) for k in a["kinematic"]])
                for a in c["actions"]
            ]
        )
        for c in candidates_doc(kinematic)
    ]
    doc = cost_arg(cost)
    targets = []
    for t in doc["targets"]:
        m = spb.CostTarget(
            object=t["object"],
            step=t["step"],
            position=pb.Vec3(x=t["position"][0], y=t["position"][1], z=t["position"][2]),
            position_weight=t["position_weight"],
            rotation_weight=t.get("rotation_weight", 0.0),
        )
        if "rotation" in t:
            x, y, z, w = t["rotation"]
            m.rotation.CopyFrom(pb.Quaternion(x=x, y=y, z=z, w=w))
        targets.append(m)
    return spb.SessionGradientRequest(
        session_id=session_id,
        candidates=candidates,
        steps=steps,
        cost=spb.GradientCost(targets=targets, smoothness=doc["smoothness"]),
        every=every,
        timeout_ms=timeout_ms,
    )


def _vec(v: pb.Vec3) -> List[float]:
    return [v.x, v.y, v.z]


def _gradients(resp: spb.GradientResponse) -> Gradients:
    """A ``GradientResponse`` as :class:`~dynaserve.gradient.Gradients`."""
    return gradients_of(
        resp.model,
        [
            (
                c.cost,
                [[(_vec(g.translation), _vec(g.rotation)) for g in s.kinematic] for s in c.steps],
                [(int(f.step), poses_np(f.poses)) for f in c.frames],
            )
            for c in resp.candidates
        ],
    )


def mesh_scene_pb(objects: Sequence[MeshObject]) -> pb.MeshScene:
    """Mesh objects as a ``MeshScene`` message (checked first; errors name ``objects[i]``)."""
    out = []
    for o in checked_objects(objects):
        m = pb.MeshObject(vertices=np.ravel(o.vertices).tolist(), material=_MATERIALS[o.material])
        if o.faces is not None:
            m.faces.extend(np.ravel(o.faces).tolist())
        if o.velocity is not None:
            m.velocity.CopyFrom(_velocity(o.velocity))
        if o.vertex_velocities is not None:
            m.vertex_velocities.extend(np.ravel(o.vertex_velocities).tolist())
        out.append(m)
    return pb.MeshScene(objects=out)


def _generate_request(
    objects: Sequence[MeshObject],
    frames: int,
    denoise_steps: int,
    sampler: str,
    samples: int,
    seed: int,
    model: str,
    timeout_ms: int,
    raw_vertices: bool,
) -> pb.GenerateRequest:
    return pb.GenerateRequest(
        model=model,
        scene=mesh_scene_pb(objects),
        frames=frames,
        denoise_steps=denoise_steps,
        sampler=_SAMPLERS[check_sampler(sampler)],
        samples=samples,
        seed=seed,
        timeout_ms=timeout_ms,
        raw_vertices=raw_vertices,
    )


def _collect(out: Collector, e: pb.GenerateEvent) -> None:
    """Adds one ``GenerateEvent`` to ``out``."""
    if e.HasField("progress"):
        p = e.progress
        out.add_progress(
            {
                "step": int(p.step),
                "steps": int(p.steps),
                "t": _f32(p.t),
                "queue_ms": float(p.timing.queue_ms),
                "forward_ms": float(p.timing.forward_ms),
                "batch_scenes": int(p.timing.batch_scenes),
            }
        )
    elif e.HasField("sample"):
        frames = [
            (f.time, [(o.vertices, pose_np(o.pose) if o.HasField("pose") else None, o.fit_rms) for o in f.objects])
            for f in e.sample.frames
        ]
        out.add_sample(e.sample.sample, e.sample.seed, frames)


def _interact_open(
    scene: Optional[Scene],
    session_id: Optional[str],
    kinematic: Sequence[int],
    dt_steps: int,
    model: str,
) -> spb.InteractRequest:
    if (scene is None) == (session_id is None):
        raise ValueError("interact needs exactly one of scene and session_id")
    if scene is None:
        assert session_id is not None
        return spb.InteractRequest(session_id=session_id)
    return spb.InteractRequest(
        create=spb.CreateSessionRequest(
            model=model, scene=scene_pb(scene), dt_steps=dt_steps, kinematic=list(kinematic)
        )
    )


def _interact_step(
    kinematic: Optional[Mapping[int, npt.ArrayLike]],
    correct: Optional[Mapping[int, npt.ArrayLike]],
    velocities: Optional[Mapping[int, npt.ArrayLike]],
) -> spb.InteractRequest:
    return spb.InteractRequest(action=action_pb(kinematic), correct=_states(correct, velocities, ("correct", "velocities")))


def _target(target: str, root_certificates: Optional[bytes]) -> Tuple[str, bool]:
    """``host:port`` and whether to use TLS, from ``host:port``, ``http://`` or ``https://``."""
    for scheme, tls in (("http://", False), ("https://", True)):
        if target.startswith(scheme):
            return target[len(scheme) :].rstrip("/"), tls
    if "://" in target or not target:
        raise ValueError(f"target must be host:port, http://host:port or https://host:port, got {target!r}")
    return target, root_certificates is not None


def _variants(
    kinematic: Optional[Sequence[Mapping[int, npt.ArrayLike]]],
    poses: Optional[Sequence[Mapping[int, npt.ArrayLike]]],
) -> List[spb.SessionVariant]:
    n = max(len(kinematic or []), len(poses or []), 1)
    return [
        spb.SessionVariant(
            actions=actions_pb(kinematic[i], f"kinematic[{i}]") if kinematic else [],
            state=_states(poses[i], names=(f"poses[{i}]", "")) if poses else [],
        )
        for i in range(n)
    ]
