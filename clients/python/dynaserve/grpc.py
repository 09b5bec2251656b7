"""Synchronous and asyncio clients of the Dynaserve gRPC API (grpcio), numpy arrays in and out.

The same surface as the HTTP :class:`~dynaserve.client.Client` (``list_models``, ``rollout``
as an iterator of frames, ``predict``, ``generate`` for PhysiFormer models, sessions created or
reattached by id), with the same arguments, defaults and argument checks, plus what only gRPC
carries: the closed ``interact`` loop (send the scene or a session id once, then one action per
step and receive each frame). Needs the ``grpc`` extra::

    pip install './clients/python[grpc]'

Poses are ``[objects, 7]`` arrays ``[x, y, z, qx, qy, qz, qw]`` (metres, unit quaternion body
to world, scalar last), trajectories ``[variants, frames, objects, 7]``. Every failure raises
:class:`~dynaserve.errors.DynaserveError` with the gRPC code name, the HTTP status the server
answers the same error with, the message and, for invalid input, the offending field path (read
from the ``google.rpc.BadRequest`` detail the server attaches to the status).

Deadlines: every unary call has ``timeout`` seconds (the client's default unless given), every
stream a whole-call deadline (``stream_timeout``), and every Interact step waits at most
``step_timeout`` seconds for its frame; past any of them the call is cancelled and
``DEADLINE_EXCEEDED`` raised. The server's own ``timeout_ms`` fields are passed through.
"""

from __future__ import annotations

import asyncio
import json
import queue
import secrets
import threading
from typing import (
    Any,
    AsyncIterator,
    Callable,
    Dict,
    Iterable,
    Iterator,
    List,
    Mapping,
    Optional,
    Sequence,
    Tuple,
    Union,
)

import numpy as np
import numpy.typing as npt

try:
    import grpc
    import grpc.aio
    from google.rpc import error_details_pb2, status_pb2
except ImportError as _missing:  # pragma: no cover - depends on the environment
    raise ImportError(
        "dynaserve.grpc needs grpcio, protobuf and googleapis-common-protos: "
        "pip install 'dynaserve[grpc]'"
    ) from _missing

from .client import AFFINITY_HEADER, Frame, spread_array
from .errors import DynaserveError, warn_out_of_range
from .mesh import Collector, Generated, MeshObject, check_sampler, checked_objects
from .scene import Body, array_arg, index_arg, kinematic_paths, number
from .v1 import sessions_pb2 as spb
from .v1 import sessions_pb2_grpc, world_model_pb2_grpc
from .v1 import world_model_pb2 as pb

DETAILS_KEY = "grpc-status-details-bin"
"""Trailer carrying the ``google.rpc.Status`` with the field of an invalid request."""
PUSHBACK_KEY = "grpc-retry-pushback-ms"
"""Trailer carrying the retry hint of an overloaded server, milliseconds."""
SESSION_KEY = "x-dynaserve-session"
"""Response header of Interact: the id of the session the stream drives."""

DEFAULT_STREAM_TIMEOUT = 600.0
"""Whole-call deadline of streaming calls (Rollout, session Step, Generate), seconds."""

# The HTTP status the server gives each gRPC code (so ``DynaserveError.status`` means the same
# over both transports).
_HTTP_STATUS = {
    "INVALID_ARGUMENT": 422,
    "OUT_OF_RANGE": 422,
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


def _trajectories(resp: pb.PredictResponse) -> np.ndarray:
    return np.stack([np.stack([poses_np(f.poses) for f in t.frames]) for t in resp.trajectories])


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
    return d


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


_OPTIONS = [
    ("grpc.max_receive_message_length", 256 * 1024 * 1024),
    ("grpc.max_send_message_length", 256 * 1024 * 1024),
]


class _Base:
    def __init__(
        self,
        target: str,
        timeout: float,
        stream_timeout: float,
        step_timeout: float,
        affinity: Optional[str],
        token: Optional[str],
        root_certificates: Optional[bytes],
    ) -> None:
        self.address, self.tls = _target(target, root_certificates)
        self.timeout = timeout
        self.stream_timeout = stream_timeout
        self.step_timeout = step_timeout
        self.affinity = affinity or secrets.token_hex(8)
        self._root_certificates = root_certificates
        self.last_request_bytes = 0
        """Encoded size of the last unary request, bytes (the planner's bandwidth figure)."""
        self.metadata: Metadata = [(AFFINITY_HEADER, self.affinity)]
        if token:
            self.metadata.append(("authorization", f"Bearer {token}"))

    def _connect(self, channels: Any) -> None:
        """Opens the channel with ``channels`` (``grpc`` or ``grpc.aio``) and its stubs."""
        if self.tls:
            creds = grpc.ssl_channel_credentials(self._root_certificates)
            self.channel = channels.secure_channel(self.address, creds, options=_OPTIONS)
        else:
            self.channel = channels.insecure_channel(self.address, options=_OPTIONS)
        self.world = world_model_pb2_grpc.WorldModelStub(self.channel)
        self.sessions = sessions_pb2_grpc.SessionsStub(self.channel)


# ---- synchronous ----


class GrpcClient(_Base):
    """A blocking client of one server's gRPC port, e.g. ``GrpcClient("127.0.0.1:50051")``.

    Args:
        target: ``host:port`` (plaintext, or TLS when ``root_certificates`` is given),
            ``http://host:port`` or ``https://host:port`` (TLS, system roots unless
            ``root_certificates``).
        timeout: deadline of every unary call, seconds.
        stream_timeout: whole-call deadline of Rollout, session Step and Generate, seconds.
        step_timeout: longest wait for one Interact frame (and for the stream to open), seconds.
        affinity: the gateway routing key sent with every call (random when ``None``).
        token: optional bearer token.
        root_certificates: PEM roots to trust for TLS.
    """

    def __init__(
        self,
        target: str = "127.0.0.1:50051",
        timeout: float = 120.0,
        stream_timeout: float = DEFAULT_STREAM_TIMEOUT,
        step_timeout: float = 60.0,
        affinity: Optional[str] = None,
        token: Optional[str] = None,
        root_certificates: Optional[bytes] = None,
    ) -> None:
        super().__init__(target, timeout, stream_timeout, step_timeout, affinity, token, root_certificates)
        self._connect(grpc)

    def close(self) -> None:
        """Closes the channel (cancelling calls still open)."""
        self.channel.close()

    def __enter__(self) -> "GrpcClient":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def _unary(self, method: Any, request: Any, timeout: Optional[float] = None) -> Any:
        self.last_request_bytes = request.ByteSize()
        try:
            resp, call = method.with_call(request, timeout=timeout or self.timeout, metadata=self.metadata)
        except grpc.RpcError as e:
            raise error_of(e) from None
        warn_out_of_range(_pairs(call.initial_metadata()))
        return resp

    # ---- stateless calls ----

    def list_models(self, timeout: Optional[float] = None) -> List[Dict[str, Any]]:
        """The resident models and their limits, as the HTTP API's ``ModelInfo`` documents."""
        resp = self._unary(self.world.ListModels, pb.ListModelsRequest(), timeout)
        return [model_info(m) for m in resp.models]

    def rollout(
        self,
        scene: Scene,
        steps: int,
        dt_steps: int = 1,
        model: str = "",
        timeout_ms: int = 0,
        timeout: Optional[float] = None,
    ) -> "FrameStream":
        """Rolls a scene forward; the returned stream yields every :class:`Frame`
        (``poses`` ``[objects, 7]``) as the server computes it. ``cancel()`` on it (or leaving
        its ``with`` block early) stops the rollout on the server. Arguments and defaults as
        for :meth:`dynaserve.Client.rollout` (``scene`` may also be a ``Scene`` message);
        ``timeout``: the whole call's deadline, seconds (default ``None``: ``stream_timeout``)."""
        req = pb.RolloutRequest(
            model=model, scene=scene_pb(scene), steps=steps, dt_steps=dt_steps, timeout_ms=timeout_ms
        )
        return FrameStream(self.world.Rollout(req, timeout=timeout or self.stream_timeout, metadata=self.metadata))

    def predict(
        self,
        variants: Sequence[Scene],
        steps: int,
        dt_steps: int = 1,
        every: int = 0,
        model: str = "",
        timeout_ms: int = 0,
        timeout: Optional[float] = None,
    ) -> np.ndarray:
        """Rolls every scene variant forward; returns ``[variants, frames, objects, 7]`` (the
        final frame only unless ``every`` > 0). Arguments and defaults as for
        :meth:`dynaserve.Client.predict`; ``timeout``: the call's deadline, seconds (default
        ``None``: the client's ``timeout``)."""
        req = pb.PredictRequest(
            model=model,
            variants=[scene_pb(v, k) for k, v in enumerate(variants)],
            steps=steps,
            dt_steps=dt_steps,
            every=every,
            timeout_ms=timeout_ms,
        )
        return _trajectories(self._unary(self.world.Predict, req, timeout))

    def generate(
        self,
        objects: Sequence[MeshObject],
        frames: int = 0,
        denoise_steps: int = 0,
        sampler: str = "heun",
        samples: int = 1,
        seed: int = 0,
        model: str = "",
        timeout_ms: int = 0,
        timeout: Optional[float] = None,
        on_progress: Optional[Callable[[dict], None]] = None,
        raw_vertices: bool = False,
    ) -> Generated:
        """Samples whole trajectories of a mesh scene with a PhysiFormer model; ``frames`` and
        ``denoise_steps`` of 0 take the model's defaults. ``on_progress`` is called once per
        denoising step. The result's ``vertices`` are ``[samples, frames, vertices, 3]``; a rigid
        object's are its frame-0 vertices moved by its fitted pose (exactly rigid) unless
        ``raw_vertices`` asks for the network's own. Arguments and defaults as for
        :meth:`dynaserve.Client.generate`; ``timeout``: the whole call's deadline, seconds
        (default ``None``: ``stream_timeout``)."""
        objects = checked_objects(objects)
        req = _generate_request(
            objects, frames, denoise_steps, sampler, samples, seed, model, timeout_ms, raw_vertices
        )
        call = self.world.Generate(req, timeout=timeout or self.stream_timeout, metadata=self.metadata)
        out = Collector(objects, on_progress)
        try:
            for e in call:
                _collect(out, e)
            md = dict(_pairs(call.initial_metadata()))
        except grpc.RpcError as e:
            raise error_of(e) from None
        return out.result(md.get("x-dynaserve-model", model), md.get("x-request-id", ""))

    # ---- sessions ----

    def create_session(
        self,
        scene: Scene,
        kinematic: Sequence[int] = (),
        dt_steps: int = 1,
        model: str = "",
        timeout: Optional[float] = None,
        shared: bool = False,
    ) -> "GrpcSession":
        """Sends a scene once and keeps it on the server with its state; ``kinematic`` lists
        the objects whose poses the caller gives every step. Arguments and defaults as for
        :meth:`dynaserve.Client.create_session`; ``timeout``: the call's deadline, seconds
        (default ``None``: the client's ``timeout``)."""
        req = spb.CreateSessionRequest(
            model=model,
            scene=scene_pb(scene),
            dt_steps=dt_steps,
            kinematic=list(kinematic),
            shared=shared,
        )
        return GrpcSession(self, self._unary(self.sessions.CreateSession, req, timeout))

    def session(self, session_id: str, timeout: Optional[float] = None) -> "GrpcSession":
        """The existing session ``session_id`` (e.g. created by another client or process),
        checked with one ``GetState`` call: ``DynaserveError`` ``NOT_FOUND`` when it is unknown
        or expired. The server's state does not report its ``model``, ``dt_steps`` or
        ``kinematic`` objects: those attributes are ``None`` on the returned session."""
        return GrpcSession(self, self._unary(self.sessions.GetState, spb.GetStateRequest(session_id=session_id), timeout))

    def interact(
        self,
        scene: Optional[Scene] = None,
        session_id: Optional[str] = None,
        kinematic: Sequence[int] = (),
        dt_steps: int = 1,
        model: str = "",
        step_timeout: Optional[float] = None,
        timeout: Optional[float] = None,
    ) -> "Interaction":
        """Opens a closed loop on a new session made from ``scene`` (deleted when the loop
        ends; ``kinematic``, ``dt_steps`` and ``model`` as in :meth:`create_session`) or on
        the existing session ``session_id``. Each :meth:`Interaction.step` then sends one
        action and returns its frame. ``timeout`` (seconds) bounds the whole loop, none by
        default; ``step_timeout`` each step."""
        first = _interact_open(scene, session_id, kinematic, dt_steps, model)
        return Interaction(self, first, step_timeout or self.step_timeout, timeout)


class FrameStream(Iterator[Frame]):
    """The frames of one streaming call, in step order; iterate it. Raises
    :class:`DynaserveError` when the call fails; ends quietly after :meth:`cancel`."""

    def __init__(self, call: Any) -> None:
        self._call = call
        self._cancelled = False
        self._warned = False

    def __iter__(self) -> "FrameStream":
        return self

    def __next__(self) -> Frame:
        try:
            f = next(self._call)
            if not self._warned:
                # The headers have arrived with the first frame.
                self._warned = True
                warn_out_of_range(_pairs(self._call.initial_metadata()))
            return frame_of(f)
        except grpc.RpcError as e:
            if self._cancelled and e.code() == grpc.StatusCode.CANCELLED:
                raise StopIteration from None
            raise error_of(e) from None

    def cancel(self) -> None:
        """Stops the call; the server frees its slot."""
        self._cancelled = True
        self._call.cancel()

    @property
    def request_id(self) -> str:
        """The server's request id (waits for the response headers)."""
        return dict(_pairs(self._call.initial_metadata())).get("x-request-id", "")

    def __enter__(self) -> "FrameStream":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.cancel()


class _SessionFields:
    """What a session object knows of its session: all of its ``SessionInfo``, or of a
    ``SessionState`` (a session reattached by id) the id, object count and expiry only."""

    def __init__(self, client: Any, info: Union[spb.SessionInfo, spb.SessionState]) -> None:
        self.client = client
        self.id: str = info.session_id
        self.expires_at_unix_ms: int = int(info.expires_at_unix_ms)
        known = isinstance(info, spb.SessionInfo)
        self.objects: int = int(info.objects) if known else len(info.poses)
        self.model: Optional[str] = info.model if known else None
        self.dt_steps: Optional[int] = int(info.dt_steps) if known else None
        self.kinematic: Optional[List[int]] = list(info.kinematic) if known else None


class GrpcSession(_SessionFields):
    """A scene kept on the server with its state, over gRPC. Kinematic paths are ``{object
    index: [steps, 7] poses}``: each kinematic object's pose at the end of every step.

    Attributes:
        id: the session id (32 hex digits).
        objects: objects in its scene.
        expires_at_unix_ms: when it expires unless used again (as of the last call that
            returned it), milliseconds since the Unix epoch.
        model: the model that serves it; ``None`` for a session reattached with
            :meth:`GrpcClient.session` (the server's state does not report it).
        dt_steps: frames per step; ``None`` when reattached.
        kinematic: indices of its kinematic objects; ``None`` when reattached.
    """

    def step(
        self,
        steps: int,
        kinematic: Optional[Mapping[int, npt.ArrayLike]] = None,
        timeout_ms: int = 0,
        timeout: Optional[float] = None,
    ) -> List[Frame]:
        """Advances the session; returns one frame per step (steps counted from the
        session's start)."""
        req = spb.StepRequest(
            session_id=self.id, steps=steps, actions=actions_pb(kinematic), timeout_ms=timeout_ms
        )
        c = self.client
        return list(FrameStream(c.sessions.Step(req, timeout=timeout or c.stream_timeout, metadata=c.metadata)))

    def state(self) -> Dict[str, Any]:
        """The current state: ``step``, ``time``, ``poses`` and ``previous_poses`` ``[objects, 7]``."""
        return _state(self.client._unary(self.client.sessions.GetState, spb.GetStateRequest(session_id=self.id)))

    def set_state(
        self,
        poses: Mapping[int, npt.ArrayLike],
        velocities: Optional[Mapping[int, npt.ArrayLike]] = None,
    ) -> Dict[str, Any]:
        """Overwrites the listed objects' poses ``{index: [7]}`` (at rest, or with velocities
        ``{index: [6]}``), e.g. from an observation; returns the new state."""
        req = spb.SetStateRequest(session_id=self.id, objects=_states(poses, velocities))
        return _state(self.client._unary(self.client.sessions.SetState, req))

    def fork(self) -> "GrpcSession":
        """A copy of this session (same scene, its own state) under a new id."""
        return GrpcSession(self.client, self.client._unary(self.client.sessions.Fork, spb.ForkRequest(session_id=self.id)))

    def predict(
        self,
        steps: int,
        kinematic: Optional[Sequence[Mapping[int, npt.ArrayLike]]] = None,
        poses: Optional[Sequence[Mapping[int, npt.ArrayLike]]] = None,
        every: int = 0,
        timeout_ms: int = 0,
        timeout: Optional[float] = None,
    ) -> np.ndarray:
        """Rolls variants of the session's state forward in one call; the session does not
        move. Variant ``i`` has its kinematic paths ``kinematic[i]`` and pose overrides
        ``poses[i]`` (``{index: [7]}``, at rest). Returns ``[variants, frames, objects, 7]``."""
        req = spb.SessionPredictRequest(
            session_id=self.id,
            variants=_variants(kinematic, poses),
            steps=steps,
            every=every,
            timeout_ms=timeout_ms,
        )
        return _trajectories(self.client._unary(self.client.sessions.Predict, req, timeout))

    def interact(self, step_timeout: Optional[float] = None, timeout: Optional[float] = None) -> "Interaction":
        """A closed loop on this session (see :meth:`GrpcClient.interact`); the session keeps
        the state the loop leaves it in."""
        return self.client.interact(session_id=self.id, step_timeout=step_timeout, timeout=timeout)

    def delete(self) -> None:
        """Deletes the session on the server."""
        self.client._unary(self.client.sessions.DeleteSession, spb.DeleteSessionRequest(session_id=self.id))


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


_END = object()


class Interaction:
    """A closed loop on one session (the ``Interact`` stream): each :meth:`step` sends one
    action and returns the frame of that step as soon as its batch has run. Use it as a
    context manager, or call :meth:`close` (end the stream, keeping a named session's state)
    or :meth:`cancel`. A stream that fails raises :class:`DynaserveError` from the step that
    sees it and accepts no further step.

    Attributes:
        session_id: the session driven (a new one when the loop was opened with a scene).
        model: the model that serves it.
        request_id: the server's request id.
    """

    def __init__(self, client: GrpcClient, first: spb.InteractRequest, step_timeout: float, timeout: Optional[float]) -> None:
        self.step_timeout = step_timeout
        self._out: "queue.Queue[Any]" = queue.Queue()
        self._in: "queue.Queue[Tuple[str, Any]]" = queue.Queue()
        self._out.put(first)
        self._done = False
        self._call = client.sessions.Interact(self._requests(), timeout=timeout, metadata=client.metadata)
        self._reader = threading.Thread(target=self._read, name="dynaserve-interact", daemon=True)
        self._reader.start()
        kind, value = self._next("opening the Interact stream")
        md = dict(value) if kind == "open" else {}
        if SESSION_KEY not in md:
            if kind == "open":
                kind, value = self._next("opening the Interact stream")
            self._finish()
            if kind == "error":
                raise error_of(value)
            raise DynaserveError(500, "UNKNOWN", "the Interact stream ended before it opened")
        warn_out_of_range(value)
        self.session_id: str = md[SESSION_KEY]
        self.model: str = md.get("x-dynaserve-model", "")
        self.request_id: str = md.get("x-request-id", "")

    def _requests(self) -> Iterator[spb.InteractRequest]:
        while True:
            m = self._out.get()
            if m is _END:
                return
            yield m

    def _read(self) -> None:
        try:
            self._in.put(("open", list(_pairs(self._call.initial_metadata()))))
            for f in self._call:
                self._in.put(("frame", f))
            self._in.put(("end", None))
        except grpc.RpcError as e:
            self._in.put(("error", e))

    def _next(self, what: str) -> Tuple[str, Any]:
        try:
            return self._in.get(timeout=self.step_timeout)
        except queue.Empty:
            self.cancel()
            raise _deadline(what, self.step_timeout) from None

    def _finish(self) -> None:
        self._done = True
        self._out.put(_END)

    def step(
        self,
        kinematic: Optional[Mapping[int, npt.ArrayLike]] = None,
        correct: Optional[Mapping[int, npt.ArrayLike]] = None,
        velocities: Optional[Mapping[int, npt.ArrayLike]] = None,
    ) -> Frame:
        """One step: the kinematic objects' poses at its end ``{index: [7]}`` (those not
        given hold still) after overwriting the states in ``correct`` ``{index: [7]}`` (at
        rest, or with ``velocities`` ``{index: [6]}``). Returns its frame, ``poses``
        ``[objects, 7]``, steps counted from the session's start."""
        if self._done:
            raise DynaserveError(499, "CANCELLED", "the Interact stream is closed")
        self._out.put(_interact_step(kinematic, correct, velocities))
        kind, value = self._next("Interact step")
        if kind == "frame":
            return frame_of(value)
        self._finish()
        if kind == "error":
            raise error_of(value)
        raise DynaserveError(500, "UNKNOWN", "the Interact stream ended without answering the step")

    def close(self) -> None:
        """Ends the stream (the server ends its side; a session created for it is deleted)."""
        if self._done:
            return
        self._finish()
        try:
            kind, value = self._next("closing the Interact stream")
        except DynaserveError:
            return
        if kind == "error" and value.code() != grpc.StatusCode.CANCELLED:
            raise error_of(value)

    def cancel(self) -> None:
        """Cancels the stream at once."""
        self._done = True
        self._call.cancel()
        self._out.put(_END)

    def __enter__(self) -> "Interaction":
        return self

    def __exit__(self, exc_type: Any, *exc: Any) -> None:
        if exc_type is None:
            self.close()
        else:
            self.cancel()


# ---- asyncio ----


class AsyncGrpcClient(_Base):
    """The calls of :class:`GrpcClient` for asyncio code (``grpc.aio``); create it inside the
    running event loop and ``await close()`` when done. Arguments as for :class:`GrpcClient`."""

    def __init__(
        self,
        target: str = "127.0.0.1:50051",
        timeout: float = 120.0,
        stream_timeout: float = DEFAULT_STREAM_TIMEOUT,
        step_timeout: float = 60.0,
        affinity: Optional[str] = None,
        token: Optional[str] = None,
        root_certificates: Optional[bytes] = None,
    ) -> None:
        super().__init__(target, timeout, stream_timeout, step_timeout, affinity, token, root_certificates)
        self._connect(grpc.aio)

    async def close(self) -> None:
        """Closes the channel."""
        await self.channel.close()

    async def __aenter__(self) -> "AsyncGrpcClient":
        return self

    async def __aexit__(self, *exc: Any) -> None:
        await self.close()

    async def _unary(self, method: Any, request: Any, timeout: Optional[float] = None) -> Any:
        self.last_request_bytes = request.ByteSize()
        try:
            call = method(request, timeout=timeout or self.timeout, metadata=self.metadata)
            resp = await call
            md = await call.initial_metadata()
        except grpc.aio.AioRpcError as e:
            raise error_of(e) from None
        warn_out_of_range(_pairs(md))
        return resp

    async def list_models(self, timeout: Optional[float] = None) -> List[Dict[str, Any]]:
        """See :meth:`GrpcClient.list_models`."""
        resp = await self._unary(self.world.ListModels, pb.ListModelsRequest(), timeout)
        return [model_info(m) for m in resp.models]

    def rollout(
        self,
        scene: Scene,
        steps: int,
        dt_steps: int = 1,
        model: str = "",
        timeout_ms: int = 0,
        timeout: Optional[float] = None,
    ) -> "AsyncFrameStream":
        """See :meth:`GrpcClient.rollout`; iterate the result with ``async for``."""
        req = pb.RolloutRequest(
            model=model, scene=scene_pb(scene), steps=steps, dt_steps=dt_steps, timeout_ms=timeout_ms
        )
        return AsyncFrameStream(self.world.Rollout(req, timeout=timeout or self.stream_timeout, metadata=self.metadata))

    async def predict(
        self,
        variants: Sequence[Scene],
        steps: int,
        dt_steps: int = 1,
        every: int = 0,
        model: str = "",
        timeout_ms: int = 0,
        timeout: Optional[float] = None,
    ) -> np.ndarray:
        """See :meth:`GrpcClient.predict`; ``[variants, frames, objects, 7]``."""
        req = pb.PredictRequest(
            model=model,
            variants=[scene_pb(v, k) for k, v in enumerate(variants)],
            steps=steps,
            dt_steps=dt_steps,
            every=every,
            timeout_ms=timeout_ms,
        )
        return _trajectories(await self._unary(self.world.Predict, req, timeout))

    async def generate(
        self,
        objects: Sequence[MeshObject],
        frames: int = 0,
        denoise_steps: int = 0,
        sampler: str = "heun",
        samples: int = 1,
        seed: int = 0,
        model: str = "",
        timeout_ms: int = 0,
        timeout: Optional[float] = None,
        on_progress: Optional[Callable[[dict], None]] = None,
        raw_vertices: bool = False,
    ) -> Generated:
        """See :meth:`GrpcClient.generate`; ``vertices`` ``[samples, frames, vertices, 3]``."""
        objects = checked_objects(objects)
        req = _generate_request(
            objects, frames, denoise_steps, sampler, samples, seed, model, timeout_ms, raw_vertices
        )
        call = self.world.Generate(req, timeout=timeout or self.stream_timeout, metadata=self.metadata)
        out = Collector(objects, on_progress)
        try:
            async for e in call:
                _collect(out, e)
            md = dict(_pairs(await call.initial_metadata()))
        except grpc.aio.AioRpcError as e:
            raise error_of(e) from None
        return out.result(md.get("x-dynaserve-model", model), md.get("x-request-id", ""))

    async def create_session(
        self,
        scene: Scene,
        kinematic: Sequence[int] = (),
        dt_steps: int = 1,
        model: str = "",
        timeout: Optional[float] = None,
        shared: bool = False,
    ) -> "AsyncGrpcSession":
        """See :meth:`GrpcClient.create_session`."""
        req = spb.CreateSessionRequest(
            model=model,
            scene=scene_pb(scene),
            dt_steps=dt_steps,
            kinematic=list(kinematic),
            shared=shared,
        )
        return AsyncGrpcSession(self, await self._unary(self.sessions.CreateSession, req, timeout))

    async def session(self, session_id: str, timeout: Optional[float] = None) -> "AsyncGrpcSession":
        """See :meth:`GrpcClient.session`."""
        req = spb.GetStateRequest(session_id=session_id)
        return AsyncGrpcSession(self, await self._unary(self.sessions.GetState, req, timeout))

    async def interact(
        self,
        scene: Optional[Scene] = None,
        session_id: Optional[str] = None,
        kinematic: Sequence[int] = (),
        dt_steps: int = 1,
        model: str = "",
        step_timeout: Optional[float] = None,
        timeout: Optional[float] = None,
    ) -> "AsyncInteraction":
        """See :meth:`GrpcClient.interact`; the loop's :meth:`AsyncInteraction.step` is awaited."""
        first = _interact_open(scene, session_id, kinematic, dt_steps, model)
        loop = AsyncInteraction(self, step_timeout or self.step_timeout, timeout)
        await loop._open(first)
        return loop


class AsyncFrameStream(AsyncIterator[Frame]):
    """The frames of one streaming call for ``async for``; see :class:`FrameStream`."""

    def __init__(self, call: Any) -> None:
        self._call = call
        self._cancelled = False
        self._warned = False

    def __aiter__(self) -> "AsyncFrameStream":
        return self

    async def __anext__(self) -> Frame:
        try:
            f = await self._call.read()
            if not self._warned and f is not grpc.aio.EOF:
                self._warned = True
                warn_out_of_range(_pairs(await self._call.initial_metadata()))
        except asyncio.CancelledError:
            if self._cancelled:
                raise StopAsyncIteration from None
            raise
        except grpc.aio.AioRpcError as e:
            if self._cancelled and e.code() == grpc.StatusCode.CANCELLED:
                raise StopAsyncIteration from None
            raise error_of(e) from None
        if f is grpc.aio.EOF:
            raise StopAsyncIteration
        return frame_of(f)

    def cancel(self) -> None:
        """Stops the call; the server frees its slot."""
        self._cancelled = True
        self._call.cancel()

    async def request_id(self) -> str:
        """The server's request id (waits for the response headers)."""
        return dict(_pairs(await self._call.initial_metadata())).get("x-request-id", "")


class AsyncGrpcSession(_SessionFields):
    """A session of :class:`AsyncGrpcClient`; the attributes and methods of
    :class:`GrpcSession`, awaited."""

    async def step(
        self,
        steps: int,
        kinematic: Optional[Mapping[int, npt.ArrayLike]] = None,
        timeout_ms: int = 0,
        timeout: Optional[float] = None,
    ) -> List[Frame]:
        """See :meth:`GrpcSession.step`."""
        req = spb.StepRequest(
            session_id=self.id, steps=steps, actions=actions_pb(kinematic), timeout_ms=timeout_ms
        )
        c = self.client
        return [f async for f in AsyncFrameStream(c.sessions.Step(req, timeout=timeout or c.stream_timeout, metadata=c.metadata))]

    async def state(self) -> Dict[str, Any]:
        """See :meth:`GrpcSession.state`."""
        return _state(await self.client._unary(self.client.sessions.GetState, spb.GetStateRequest(session_id=self.id)))

    async def set_state(
        self,
        poses: Mapping[int, npt.ArrayLike],
        velocities: Optional[Mapping[int, npt.ArrayLike]] = None,
    ) -> Dict[str, Any]:
        """See :meth:`GrpcSession.set_state`."""
        req = spb.SetStateRequest(session_id=self.id, objects=_states(poses, velocities))
        return _state(await self.client._unary(self.client.sessions.SetState, req))

    async def fork(self) -> "AsyncGrpcSession":
        """See :meth:`GrpcSession.fork`."""
        info = await self.client._unary(self.client.sessions.Fork, spb.ForkRequest(session_id=self.id))
        return AsyncGrpcSession(self.client, info)

    async def predict(
        self,
        steps: int,
        kinematic: Optional[Sequence[Mapping[int, npt.ArrayLike]]] = None,
        poses: Optional[Sequence[Mapping[int, npt.ArrayLike]]] = None,
        every: int = 0,
        timeout_ms: int = 0,
        timeout: Optional[float] = None,
    ) -> np.ndarray:
        """See :meth:`GrpcSession.predict`; ``[variants, frames, objects, 7]``."""
        req = spb.SessionPredictRequest(
            session_id=self.id,
            variants=_variants(kinematic, poses),
            steps=steps,
            every=every,
            timeout_ms=timeout_ms,
        )
        return _trajectories(await self.client._unary(self.client.sessions.Predict, req, timeout))

    async def interact(self, step_timeout: Optional[float] = None, timeout: Optional[float] = None) -> "AsyncInteraction":
        """See :meth:`GrpcSession.interact`."""
        return await self.client.interact(session_id=self.id, step_timeout=step_timeout, timeout=timeout)

    async def delete(self) -> None:
        """See :meth:`GrpcSession.delete`."""
        await self.client._unary(self.client.sessions.DeleteSession, spb.DeleteSessionRequest(session_id=self.id))


class AsyncInteraction:
    """The closed loop of :class:`Interaction` for asyncio: ``await step(...)``; use it with
    ``async with`` or ``await close()``."""

    def __init__(self, client: AsyncGrpcClient, step_timeout: float, timeout: Optional[float]) -> None:
        self.step_timeout = step_timeout
        self._call = client.sessions.Interact(timeout=timeout, metadata=client.metadata)
        self._done = False
        self.session_id = ""
        self.model = ""
        self.request_id = ""

    async def _wait(self, what: str, aw: Any) -> Any:
        try:
            return await asyncio.wait_for(aw, self.step_timeout)
        except asyncio.TimeoutError:
            self.cancel()
            raise _deadline(what, self.step_timeout) from None
        except grpc.aio.AioRpcError as e:
            self._done = True
            raise error_of(e) from None

    async def _open(self, first: spb.InteractRequest) -> None:
        await self._wait("opening the Interact stream", self._call.write(first))
        pairs = list(_pairs(await self._wait("opening the Interact stream", self._call.initial_metadata())))
        md = dict(pairs)
        if SESSION_KEY not in md:
            # The stream failed before it opened: reading surfaces its status.
            await self._wait("opening the Interact stream", self._call.read())
            self._done = True
            raise DynaserveError(500, "UNKNOWN", "the Interact stream ended before it opened")
        warn_out_of_range(pairs)
        self.session_id = md[SESSION_KEY]
        self.model = md.get("x-dynaserve-model", "")
        self.request_id = md.get("x-request-id", "")

    async def step(
        self,
        kinematic: Optional[Mapping[int, npt.ArrayLike]] = None,
        correct: Optional[Mapping[int, npt.ArrayLike]] = None,
        velocities: Optional[Mapping[int, npt.ArrayLike]] = None,
    ) -> Frame:
        """See :meth:`Interaction.step`."""
        if self._done:
            raise DynaserveError(499, "CANCELLED", "the Interact stream is closed")
        await self._wait("Interact step", self._call.write(_interact_step(kinematic, correct, velocities)))
        f = await self._wait("Interact step", self._call.read())
        if f is grpc.aio.EOF:
            self._done = True
            raise DynaserveError(500, "UNKNOWN", "the Interact stream ended without answering the step")
        return frame_of(f)

    async def close(self) -> None:
        """See :meth:`Interaction.close`."""
        if self._done:
            return
        self._done = True
        await self._wait("closing the Interact stream", self._call.done_writing())
        await self._wait("closing the Interact stream", self._call.read())

    def cancel(self) -> None:
        """Cancels the stream at once."""
        self._done = True
        self._call.cancel()

    async def __aenter__(self) -> "AsyncInteraction":
        return self

    async def __aexit__(self, exc_type: Any, *exc: Any) -> None:
        if exc_type is None:
            await self.close()
        else:
            self.cancel()
