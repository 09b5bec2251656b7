"""Synchronous and asyncio clients of the Dynaserve HTTP API (standard library HTTP, numpy
arrays in and out).

Poses are ``[objects, 7]`` arrays (``[x, y, z, qx, qy, qz, qw]``), trajectories
``[frames, objects, 7]``. Array arguments are checked before anything is sent: a wrong shape or
a value that is not finite raises ``ValueError`` naming the argument, e.g. ``bodies[0].points:
expected [N, 3], got shape (3, 5)``. Every failure of a call raises
:class:`~dynaserve.errors.DynaserveError` with the server's code, message and field path; a
server that cannot be reached is ``UNAVAILABLE`` (503), one that does not answer within the
socket timeout ``DEADLINE_EXCEEDED`` (504), as over gRPC.

Scale-out: every call carries the ``x-dynaserve-affinity`` header (one random key per client
unless given), so that a gateway hashing it sends all calls of a session and of its forks to
the replica that holds them.
"""

from __future__ import annotations

import asyncio
import contextlib
import http.client
import json
import math
import secrets
import socket
import urllib.parse
from dataclasses import dataclass
from typing import Any, Callable, Dict, Iterator, List, Literal, Mapping, Optional, Sequence, Tuple, overload

import numpy as np
import numpy.typing as npt

from .errors import DynaserveError, warn_out_of_range
from .gradient import Gradients, candidates_doc, cost_arg, gradients_from_doc
from .mesh import Collector, Generated, MeshObject, check_sampler, checked_objects
from .scene import actions_doc, object_state_doc, pose_array, poses_array, scene_doc

AFFINITY_HEADER = "x-dynaserve-affinity"


@dataclass
class Frame:
    """The state after one step: ``poses`` ``[objects, 7]`` at ``time`` seconds (step ``step``,
    counted from 1; within a session from the session's start). ``spread`` ``[objects, 2]``:
    each object's spread of this step's prediction, ``[position_m, orientation_deg]`` (an
    ensemble's members' weighted RMS disagreement, metres and degrees; row ``j`` belongs to
    object ``j``); ``None`` when the model estimates none."""

    step: int
    time: float
    poses: np.ndarray
    spread: Optional[np.ndarray] = None


def spread_array(entries: Sequence[Any]) -> Optional[np.ndarray]:
    """``[objects, 2]`` (``position_m``, ``orientation_deg``) from a frame's spread entries
    (JSON objects or ``ObjectSpread`` messages); ``None`` for none."""
    if not entries:
        return None
    get = (lambda e, k: e[k]) if isinstance(entries[0], dict) else getattr
    return np.array(
        [[float(get(e, "position_m")), float(get(e, "orientation_deg"))] for e in entries],
        dtype=np.float32,
    )


PosesAndSpread = Tuple[np.ndarray, Optional[np.ndarray]]
"""What ``predict(..., with_spread=True)`` returns: the poses ``[variants, frames, objects,
7]`` and the spread ``[variants, frames, objects, 2]`` (``[position_m, orientation_deg]``,
metres and degrees, as :attr:`Frame.spread`), or ``None`` when the model estimates none."""


def predict_arrays(
    frames: Sequence[Sequence[Tuple[np.ndarray, Optional[np.ndarray]]]], with_spread: bool
) -> Any:
    """A Predict response's poses ``[variants, frames, objects, 7]`` from ``frames[i][k]``
    ``(poses [objects, 7], spread [objects, 2] or None)`` of variant ``i``'s frame ``k``; with
    ``with_spread``, ``(poses, spread)`` (:data:`PosesAndSpread`), the spread ``None`` when no
    frame carries one. Frames of which only some carry a spread, or one of another length
    than their poses, are a ``ValueError`` naming the first such frame."""
    poses = np.stack([np.stack([p for p, _ in t]) for t in frames])
    if not with_spread:
        return poses
    if all(s is None for t in frames for _, s in t):
        return poses, None
    for i, t in enumerate(frames):
        for k, (p, s) in enumerate(t):
            if s is None or s.shape != (len(p), 2):
                got = "no spread" if s is None else f"spread of shape {s.shape}"
                raise ValueError(f"trajectories[{i}].frames[{k}]: {got} for {len(p)} objects, unlike other frames")
    return poses, np.stack([np.stack([s for _, s in t]) for t in frames])


def _frame(doc: Dict[str, Any]) -> Frame:
    return Frame(
        step=int(doc["step"]),
        time=float(doc["time"]),
        poses=poses_array(doc["poses"]),
        spread=spread_array(doc.get("spread", [])),
    )


def _scene(scene: Any, variant: Optional[int] = None) -> Dict[str, Any]:
    """A scene given as bodies (errors name ``bodies[i]``, or ``variants[k][i]`` for the
    variant ``k`` of a Predict call) or as a ready JSON document."""
    if isinstance(scene, Mapping):
        return dict(scene)
    return scene_doc(list(scene), "bodies" if variant is None else f"variants[{variant}]")


def _not_finite(x: Any, path: str) -> Optional[Tuple[str, float]]:
    """The path and value of the first number in a JSON document that is not finite."""
    if isinstance(x, float):
        return None if math.isfinite(x) else (path, x)
    if isinstance(x, Mapping):
        items: Any = ((f"{path}.{k}" if path else str(k), v) for k, v in x.items())
    elif isinstance(x, (list, tuple)):
        items = ((f"{path}[{i}]", v) for i, v in enumerate(x))
    else:
        return None
    for p, v in items:
        found = _not_finite(v, p)
        if found:
            return found
    return None


def _encode(body: Dict[str, Any]) -> bytes:
    """The JSON of a request body; a number that is not finite (which JSON cannot carry) is
    a ``ValueError`` naming its field, e.g. ``scene.objects[0].mass: nan is not finite``."""
    try:
        return json.dumps(body, allow_nan=False).encode()
    except ValueError:
        found = _not_finite(body, "")
        if found is None:
            raise
        raise ValueError(f"{found[0]}: {found[1]} is not finite") from None


class Client:
    """A client of one server's HTTP API, e.g. ``Client("http://127.0.0.1:8080")``.

    Args:
        base_url: the server's HTTP address, ``http(s)://host:port``. Default
            ``"http://127.0.0.1:8080"``.
        timeout: socket timeout of every connect and read, seconds. Default 120.
        affinity: the gateway routing key sent with every call. Default ``None``: a random
            key per client.
        token: bearer token sent with every call. Default ``None``: none.
    """

    def __init__(
        self,
        base_url: str = "http://127.0.0.1:8080",
        timeout: float = 120.0,
        affinity: Optional[str] = None,
        token: Optional[str] = None,
    ) -> None:
        u = urllib.parse.urlsplit(base_url)
        if u.scheme not in ("http", "https") or not u.hostname:
            raise ValueError(f"base_url must be http(s)://host:port, got {base_url!r}")
        self._https = u.scheme == "https"
        self._host = u.hostname
        self._port = u.port or (443 if self._https else 80)
        self.base_url = f"{u.scheme}://{self._host}:{self._port}"
        self.timeout = timeout
        self.affinity = affinity or secrets.token_hex(8)
        self._token = token
        self.last_request_bytes = 0

    # ---- transport ----

    def _conn(self, timeout: Optional[float] = None) -> http.client.HTTPConnection:
        cls = http.client.HTTPSConnection if self._https else http.client.HTTPConnection
        return cls(self._host, self._port, timeout=timeout or self.timeout)

    def _headers(self, extra: Optional[Dict[str, str]] = None) -> Dict[str, str]:
        h = {"content-type": "application/json", AFFINITY_HEADER: self.affinity}
        if self._token:
            h["authorization"] = f"Bearer {self._token}"
        h.update(extra or {})
        return h

    @contextlib.contextmanager
    def _reaching(self, timeout: Optional[float] = None) -> Iterator[None]:
        """Turns a failure to reach the server into a :class:`DynaserveError`, as gRPC does:
        ``UNAVAILABLE`` (503) naming the address, or ``DEADLINE_EXCEEDED`` (504) after the
        socket timeout."""
        try:
            yield
        except socket.timeout as e:
            raise DynaserveError(
                504, "DEADLINE_EXCEEDED", f"{self.base_url}: no answer within {timeout or self.timeout} s"
            ) from e
        except (OSError, http.client.HTTPException) as e:
            raise DynaserveError(503, "UNAVAILABLE", f"cannot reach {self.base_url}: {e}") from e

    def _open(
        self,
        method: str,
        path: str,
        body: Optional[Dict[str, Any]] = None,
        sse: bool = False,
        timeout: Optional[float] = None,
    ) -> Tuple[http.client.HTTPConnection, http.client.HTTPResponse]:
        """Sends one request; returns the connection and the successful response (the caller
        closes the connection). An error answer raises its :class:`DynaserveError`."""
        data = _encode(body) if body is not None else None
        self.last_request_bytes = len(data or b"")
        conn = self._conn(timeout)
        try:
            with self._reaching(timeout):
                conn.request(method, path, body=data, headers=self._headers({"accept": "text/event-stream"} if sse else None))
                resp = conn.getresponse()
                if resp.status >= 400:
                    raise _error(resp.status, resp.read())
        except BaseException:
            conn.close()
            raise
        return conn, resp

    def _events(self, resp: http.client.HTTPResponse, timeout: Optional[float] = None) -> Iterator[Tuple[str, Any]]:
        """The ``(event, payload)`` pairs of a Server-Sent Events answer; an ``error`` event
        raises its :class:`DynaserveError`."""
        event, data = "", []
        with self._reaching(timeout):
            for line in resp:
                text = line.decode().rstrip("\r\n")
                if text.startswith("event:"):
                    event = text[6:].strip()
                elif text.startswith("data:"):
                    data.append(text[5:].strip())
                elif text == "" and data:
                    payload = json.loads("\n".join(data))
                    if event == "error":
                        raise _error_of(200, payload["error"])
                    yield event, payload
                    event, data = "", []

    def request(self, method: str, path: str, body: Optional[Dict[str, Any]] = None) -> Any:
        """Sends one request and returns the decoded JSON answer (``None`` for 204).

        Args:
            method: ``GET``, ``POST``, ``PUT`` or ``DELETE``.
            path: e.g. ``/v1/models``.
            body: the JSON document to send. Default ``None``: no body.
        """
        conn, resp = self._open(method, path, body)
        try:
            with self._reaching():
                raw = resp.read()
        finally:
            conn.close()
        warn_out_of_range(resp.getheaders())
        return json.loads(raw) if raw else None

    # ---- stateless calls ----

    def list_models(self) -> List[Dict[str, Any]]:
        """The resident models and their limits (``ModelInfo`` documents)."""
        return self.request("GET", "/v1/models")["models"]

    def rollout(
        self,
        scene: Any,
        steps: int,
        dt_steps: int = 1,
        model: str = "",
        timeout_ms: int = 0,
    ) -> Iterator[Frame]:
        """Rolls a scene forward and yields every :class:`Frame` (``poses`` ``[objects, 7]``)
        as the server streams it (Server-Sent Events).

        Args:
            scene: the bodies (a sequence of :class:`~dynaserve.Body`) or a ``Scene`` JSON
                document (e.g. the ``scene`` of a file in ``examples/scenes/``).
            steps: steps to produce.
            dt_steps: frames per step (``dt_steps * dt_frame`` seconds each). Default 1.
            model: the model's name. Default ``""``: the one resident RigidFormer.
            timeout_ms: the server's deadline for the whole call, milliseconds. Default 0:
                none.
        """
        body = {
            "model": model,
            "scene": _scene(scene),
            "steps": steps,
            "dt_steps": dt_steps,
            "timeout_ms": timeout_ms,
        }
        conn, resp = self._open("POST", "/v1/rollout", body, sse=True)
        try:
            warn_out_of_range(resp.getheaders())
            for event, payload in self._events(resp):
                if event == "frame":
                    yield _frame(payload)
                elif event == "done":
                    return
        finally:
            conn.close()

    @overload
    def predict(
        self, variants: Sequence[Any], steps: int, dt_steps: int = ..., every: int = ..., model: str = ...,
        timeout_ms: int = ..., *, with_spread: Literal[False] = ...,
    ) -> np.ndarray: ...

    @overload
    def predict(
        self, variants: Sequence[Any], steps: int, dt_steps: int = ..., every: int = ..., model: str = ...,
        timeout_ms: int = ..., *, with_spread: Literal[True],
    ) -> PosesAndSpread: ...

    def predict(
        self,
        variants: Sequence[Any],
        steps: int,
        dt_steps: int = 1,
        every: int = 0,
        model: str = "",
        timeout_ms: int = 0,
        *,
        with_spread: bool = False,
    ) -> Any:
        """Rolls every scene variant forward in one call; returns ``[variants, frames,
        objects, 7]``, or with ``with_spread`` ``(poses, spread)``.

        Args:
            variants: scenes, each as in :meth:`rollout`.
            steps: steps to roll each variant.
            dt_steps: frames per step. Default 1.
            every: keep every ``every``-th step's poses. Default 0: the final frame only.
            model: as in :meth:`rollout`. Default ``""``.
            timeout_ms: the server's deadline, milliseconds. Default 0: none.
            with_spread: also return each returned frame's per-object spread, ``(poses,
                spread)`` with spread ``[variants, frames, objects, 2]`` float32
                (``[position_m, orientation_deg]``: an ensemble's RMS disagreement, metres and
                degrees), or ``None`` when the model estimates none (a single network, the
                simulator). Keyword only. Default ``False``: the poses array alone.
        """
        out = self.request(
            "POST",
            "/v1/predict",
            {
                "model": model,
                "variants": [_scene(v, k) for k, v in enumerate(variants)],
                "steps": steps,
                "dt_steps": dt_steps,
                "every": every,
                "timeout_ms": timeout_ms,
            },
        )
        return _trajectories(out, with_spread)

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
        """Samples whole trajectories of a mesh scene with a PhysiFormer model
        (``POST /v1/generate``, streamed so that progress arrives per denoising step). The
        result's ``vertices`` are ``[samples, frames, vertices, 3]``; a rigid object's are its
        frame-0 vertices moved by its fitted pose (exactly rigid) unless ``raw_vertices``.
        The same call as :meth:`dynaserve.grpc.GrpcClient.generate`.

        Args:
            objects: the scene's :class:`~dynaserve.MeshObject`\ s at frame 0.
            frames: frames to sample, frame 0 included. Default 0: the model's ``max_frames``.
            denoise_steps: denoising steps. Default 0: the model's ``default_denoise_steps``.
            sampler: ``"heun"`` or ``"euler"``. Default ``"heun"``.
            samples: independent samples. Default 1.
            seed: seed of the starting noise; sample ``i`` uses ``seed + i``. Default 0.
            model: the model's name. Default ``""``: the one resident PhysiFormer.
            timeout_ms: the server's deadline, milliseconds. Default 0: none.
            timeout: socket timeout of this call, seconds. Default ``None``: the client's.
            on_progress: called with each denoising step's progress entry (see
                :class:`~dynaserve.Generated`). Default ``None``.
            raw_vertices: return rigid objects' vertices as sampled. Default ``False``.
        """
        objects = checked_objects(objects)
        body = {
            "model": model,
            "scene": {"objects": [o.doc() for o in objects]},
            "frames": frames,
            "denoise_steps": denoise_steps,
            "sampler": check_sampler(sampler),
            "samples": samples,
            "seed": seed,
            "timeout_ms": timeout_ms,
            "raw_vertices": raw_vertices,
        }
        conn, resp = self._open("POST", "/v1/generate", body, sse=True, timeout=timeout)
        out = Collector(objects, on_progress)
        try:
            warn_out_of_range(resp.getheaders())
            for event, d in self._events(resp, timeout):
                if event == "progress":
                    t = d["timing"]
                    out.add_progress(
                        {
                            "step": int(d["step"]),
                            "steps": int(d["steps"]),
                            "t": float(d["t"]),
                            "queue_ms": float(t["queue_ms"]),
                            "forward_ms": float(t["forward_ms"]),
                            "batch_scenes": int(t["batch_scenes"]),
                        }
                    )
                elif event == "sample":
                    frames_of = [
                        (f["time"], [(o["vertices"], pose_array(o["pose"]) if "pose" in o else None, o.get("fit_rms")) for o in f["objects"]])
                        for f in d["frames"]
                    ]
                    out.add_sample(d["sample"], d["seed"], frames_of)
                elif event == "done":
                    break
        finally:
            conn.close()
        return out.result(resp.getheader("x-dynaserve-model") or model, resp.getheader("x-request-id") or "")

    # ---- sessions ----

    def create_session(
        self,
        scene: Any,
        kinematic: Sequence[int] = (),
        dt_steps: int = 1,
        model: str = "",
        shared: bool = False,
    ) -> "Session":
        """Sends a scene once and keeps it on the server with its state.

        Args:
            scene: as in :meth:`rollout`.
            kinematic: the objects whose poses the caller gives every step. Default ``()``:
                none.
            dt_steps: frames per step. Default 1.
            model: as in :meth:`rollout`. Default ``""``.
            shared: let every caller use the session (step, read, set, fork); only its
                creator may delete it. Default ``False``: the session belongs to its creator
                (its bearer token, or without authentication its IP address) and is not
                found for anyone else.
        """
        body: Dict[str, Any] = {
            "model": model,
            "scene": _scene(scene),
            "dt_steps": dt_steps,
            "kinematic": list(kinematic),
        }
        if shared:
            body["shared"] = True
        info = self.request("POST", "/v1/sessions", body)
        return Session(self, info)

    def session(self, session_id: str) -> "Session":
        """The existing session ``session_id`` (e.g. created by another client or process),
        checked with one ``GET``: ``DynaserveError`` ``NOT_FOUND`` when it is unknown or
        expired. The server's state does not report its ``model``, ``dt_steps`` or
        ``kinematic`` objects: those attributes are ``None`` on the returned session."""
        return Session(self, self.request("GET", _session_path(session_id)))


def _session_path(session_id: str) -> str:
    return "/v1/sessions/" + urllib.parse.quote(session_id, safe="")


def _trajectories(out: Dict[str, Any], with_spread: bool = False) -> Any:
    """A ``PredictResponse`` document's poses, or ``(poses, spread)``: see :func:`predict_arrays`."""
    return predict_arrays(
        [
            [(poses_array(f["poses"]), spread_array(f.get("spread", []))) for f in t["frames"]]
            for t in out["trajectories"]
        ],
        with_spread,
    )


def _error_of(status: int, e: Dict[str, Any]) -> DynaserveError:
    return DynaserveError(status, e["code"], e["message"], e.get("field"), e.get("retry_after_ms"))


def _error(status: int, raw: bytes) -> DynaserveError:
    try:
        return _error_of(status, json.loads(raw)["error"])
    except (ValueError, KeyError, TypeError):
        return DynaserveError(status, "UNKNOWN", raw.decode(errors="replace"))


class Session:
    """A scene kept on the server with its state. Kinematic paths are ``{object index:
    [steps, 7] poses}``: each kinematic object's pose at the end of every step.

    Attributes:
        id: the session id (32 hex digits).
        objects: objects in its scene.
        expires_at_unix_ms: when it expires unless used again (as of the last call that
            returned it), milliseconds since the Unix epoch.
        model: the model that serves it; ``None`` for a session reattached with
            :meth:`Client.session` (the server's state does not report it).
        dt_steps: frames per step; ``None`` when reattached.
        kinematic: indices of its kinematic objects; ``None`` when reattached.
    """

    def __init__(self, client: Client, info: Dict[str, Any]) -> None:
        # ``info``: a ``SessionInfo`` document, or the ``SessionState`` of a reattached session.
        self.client = client
        self.id: str = info["session_id"]
        self.expires_at_unix_ms: int = int(info["expires_at_unix_ms"])
        known = "dt_steps" in info
        self.objects: int = int(info["objects"]) if known else len(info["poses"])
        self.model: Optional[str] = info["model"] if known else None
        self.dt_steps: Optional[int] = int(info["dt_steps"]) if known else None
        self.kinematic: Optional[List[int]] = list(info.get("kinematic", [])) if known else None

    @property
    def _path(self) -> str:
        return _session_path(self.id)

    def step(
        self,
        steps: int,
        kinematic: Optional[Mapping[int, npt.ArrayLike]] = None,
        timeout_ms: int = 0,
    ) -> List[Frame]:
        """Advances the session; returns one frame per step (steps counted from the session's
        start).

        Args:
            steps: steps to take.
            kinematic: the kinematic objects' paths ``{index: [steps, 7]}``. Default
                ``None``: they hold still.
            timeout_ms: the server's deadline, milliseconds. Default 0: none.
        """
        out = self.client.request(
            "POST",
            f"{self._path}/step",
            {"steps": steps, "actions": actions_doc(kinematic or {}), "timeout_ms": timeout_ms},
        )
        return [_frame(f) for f in out["frames"]]

    def state(self) -> Dict[str, Any]:
        """The current state: ``step``, ``time``, ``poses`` and ``previous_poses`` ``[objects, 7]``."""
        return _state(self.client.request("GET", self._path))

    def set_state(
        self,
        poses: Mapping[int, npt.ArrayLike],
        velocities: Optional[Mapping[int, npt.ArrayLike]] = None,
    ) -> Dict[str, Any]:
        """Overwrites the listed objects' states, e.g. from an observation; returns the new
        state.

        Args:
            poses: ``{index: [7]}``.
            velocities: ``{index: [6]}`` (linear m/s, angular rad/s, world frame) for some of
                those objects. Default ``None``: all at rest.
        """
        velocities = velocities or {}
        body = {"objects": [object_state_doc(j, p, velocities.get(j)) for j, p in poses.items()]}
        return _state(self.client.request("PUT", f"{self._path}/state", body))

    def fork(self) -> "Session":
        """A copy of this session (same scene, its own state) under a new id."""
        return Session(self.client, self.client.request("POST", f"{self._path}/fork"))

    @overload
    def predict(
        self, steps: int, kinematic: Optional[Sequence[Mapping[int, npt.ArrayLike]]] = ...,
        poses: Optional[Sequence[Mapping[int, npt.ArrayLike]]] = ..., every: int = ..., timeout_ms: int = ...,
        *, with_spread: Literal[False] = ...,
    ) -> np.ndarray: ...

    @overload
    def predict(
        self, steps: int, kinematic: Optional[Sequence[Mapping[int, npt.ArrayLike]]] = ...,
        poses: Optional[Sequence[Mapping[int, npt.ArrayLike]]] = ..., every: int = ..., timeout_ms: int = ...,
        *, with_spread: Literal[True],
    ) -> PosesAndSpread: ...

    def predict(
        self,
        steps: int,
        kinematic: Optional[Sequence[Mapping[int, npt.ArrayLike]]] = None,
        poses: Optional[Sequence[Mapping[int, npt.ArrayLike]]] = None,
        every: int = 0,
        timeout_ms: int = 0,
        *,
        with_spread: bool = False,
    ) -> Any:
        """Rolls variants of the session's state forward in one call; the session does not
        move. Returns ``[variants, frames, objects, 7]``, or with ``with_spread`` ``(poses,
        spread)``.

        Args:
            steps: steps to roll each variant.
            kinematic: variant ``i``'s kinematic paths ``kinematic[i]`` (``{index: [steps,
                7]}``). Default ``None``: the kinematic objects hold still.
            poses: variant ``i``'s pose overrides ``poses[i]`` (``{index: [7]}``, at rest).
                Default ``None``: the session's state.
            every: keep every ``every``-th step's poses. Default 0: the final frame only.
            timeout_ms: the server's deadline, milliseconds. Default 0: none.
            with_spread: also return the spread ``[variants, frames, objects, 2]`` (``None``
                when the model estimates none), as for :meth:`Client.predict`. Keyword only.
                Default ``False``: the poses array alone.
        """
        n = max(len(kinematic or []), len(poses or []), 1)
        variants = []
        for i in range(n):
            v: Dict[str, Any] = {}
            if kinematic:
                v["actions"] = actions_doc(kinematic[i], f"kinematic[{i}]")
            if poses:
                v["state"] = [object_state_doc(j, p, names=(f"poses[{i}]", "")) for j, p in poses[i].items()]
            variants.append(v)
        out = self.client.request(
            "POST",
            f"{self._path}/predict",
            {"variants": variants, "steps": steps, "every": every, "timeout_ms": timeout_ms},
        )
        return _trajectories(out, with_spread)

    def gradient(
        self,
        steps: int,
        kinematic: Sequence[Mapping[int, npt.ArrayLike]],
        cost: Any = None,
        every: int = 0,
        timeout_ms: int = 0,
    ) -> Gradients:
        """Scores candidate paths of the kinematic objects from the session's state and
        differentiates the score (``POST /v1/sessions/{id}/gradient``); the session does not
        move. Returns a :class:`~dynaserve.gradient.Gradients`: ``cost`` ``[candidates]``,
        ``translation`` and ``rotation`` ``[candidates, steps, kinematic, 3]``, the rollout's
        ``poses`` ``[candidates, frames, objects, 7]``. A model that computes no gradients (an
        ensemble, the simulator; ``list_models()``' ``gradients``) raises ``DynaserveError``
        ``FAILED_PRECONDITION`` (400).

        Args:
            steps: steps of every candidate.
            kinematic: candidate ``i``'s paths ``kinematic[i]`` (``{index: [steps, 7]}``), one
                for every kinematic object, as for :meth:`predict`.
            cost: the ``GradientCost`` document (see :func:`~dynaserve.gradient_cost`) or a
                sequence of its targets. Default ``None``: zero.
            every: also return every ``every``-th step's poses. Default 0: the final step's.
            timeout_ms: the server's deadline, milliseconds. Default 0: none.
        """
        body = {
            "candidates": candidates_doc(kinematic),
            "steps": steps,
            "cost": cost_arg(cost),
            "every": every,
            "timeout_ms": timeout_ms,
        }
        return gradients_from_doc(self.client.request("POST", f"{self._path}/gradient", body), poses_array)

    def delete(self) -> None:
        """Deletes the session on the server."""
        self.client.request("DELETE", self._path)


def _state(doc: Dict[str, Any]) -> Dict[str, Any]:
    return {
        "step": int(doc["step"]),
        "time": float(doc["time"]),
        "poses": poses_array(doc["poses"]),
        "previous_poses": poses_array(doc["previous_poses"]),
        "expires_at_unix_ms": int(doc["expires_at_unix_ms"]),
    }


class AsyncClient:
    """The same calls as :class:`Client` for asyncio code: each runs the blocking call on a
    worker thread (``asyncio.to_thread``), so many can be in flight at once."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.sync = Client(*args, **kwargs)

    async def list_models(self) -> List[Dict[str, Any]]:
        """See :meth:`Client.list_models`."""
        return await asyncio.to_thread(self.sync.list_models)

    @overload
    async def predict(self, *args: Any, with_spread: Literal[False] = ..., **kwargs: Any) -> np.ndarray: ...

    @overload
    async def predict(self, *args: Any, with_spread: Literal[True], **kwargs: Any) -> PosesAndSpread: ...

    async def predict(self, *args: Any, with_spread: bool = False, **kwargs: Any) -> Any:
        """See :meth:`Client.predict` (``with_spread`` included)."""
        return await asyncio.to_thread(lambda: self.sync.predict(*args, with_spread=with_spread, **kwargs))

    async def rollout(self, *args: Any, **kwargs: Any) -> List[Frame]:
        """See :meth:`Client.rollout`; returns the whole list of frames."""
        return await asyncio.to_thread(lambda: list(self.sync.rollout(*args, **kwargs)))

    async def generate(self, *args: Any, **kwargs: Any) -> Generated:
        """See :meth:`Client.generate`."""
        return await asyncio.to_thread(self.sync.generate, *args, **kwargs)

    async def create_session(self, *args: Any, **kwargs: Any) -> Session:
        """See :meth:`Client.create_session` (the session's own methods are blocking; wrap
        them with ``asyncio.to_thread``)."""
        return await asyncio.to_thread(self.sync.create_session, *args, **kwargs)

    async def session(self, session_id: str) -> Session:
        """See :meth:`Client.session`."""
        return await asyncio.to_thread(self.sync.session, session_id)
