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

This module holds the synchronous classes (:class:`GrpcClient`, :class:`FrameStream`,
:class:`GrpcSession`, :class:`Interaction`) and re-exports the rest of the public surface: the
asyncio classes from :mod:`dynaserve.grpc_async`, the message conversions and metadata keys from
:mod:`dynaserve.grpc_convert`, ``DEFAULT_STREAM_TIMEOUT`` from :mod:`dynaserve.grpc_base`.
"""

from __future__ import annotations

import queue
import threading
from typing import (
    Any,
    Callable,
    Dict,
    Iterator,
    List,
    Literal,
    Mapping,
    Optional,
    Sequence,
    Tuple,
    overload,
)

import numpy as np
import numpy.typing as npt

try:
    import grpc
    import grpc.aio
    # Used by .grpc_convert and .grpc_async; imported here so that a missing package of the
    # grpc extra gets the message below.
    from google.rpc import error_details_pb2, status_pb2  # noqa: F401
except ImportError as _missing:  # pragma: no cover - depends on the environment
    raise ImportError(
        "dynaserve.grpc needs grpcio, protobuf and googleapis-common-protos: "
        "pip install 'dynaserve[grpc]'"
    ) from _missing

from .client import Frame, PosesAndSpread
from .errors import DynaserveError, warn_out_of_range
from .gradient import Gradients
from .grpc_async import AsyncFrameStream, AsyncGrpcClient, AsyncGrpcSession, AsyncInteraction
from .grpc_base import DEFAULT_STREAM_TIMEOUT, _Base, _SessionFields
from .grpc_convert import (
    DETAILS_KEY,
    PUSHBACK_KEY,
    SESSION_KEY,
    Metadata,
    Scene,
    _collect,
    _deadline,
    _generate_request,
    _gradient_request,
    _gradients,
    _interact_open,
    _interact_step,
    _pairs,
    _state,
    _states,
    _trajectories,
    _variants,
    action_pb,
    actions_pb,
    error_of,
    frame_of,
    mesh_scene_pb,
    model_info,
    object_doc_pb,
    object_spec,
    object_state_pb,
    pose_np,
    pose_pb,
    poses_np,
    scene_pb,
)
from .mesh import Collector, Generated, MeshObject, checked_objects
from .v1 import sessions_pb2 as spb
from .v1 import world_model_pb2 as pb


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

    @overload
    def predict(
        self, variants: Sequence[Scene], steps: int, dt_steps: int = ..., every: int = ..., model: str = ...,
        timeout_ms: int = ..., timeout: Optional[float] = ...,
        *, with_spread: Literal[False] = ...,
    ) -> np.ndarray: ...

    @overload
    def predict(
        self, variants: Sequence[Scene], steps: int, dt_steps: int = ..., every: int = ..., model: str = ...,
        timeout_ms: int = ..., timeout: Optional[float] = ...,
        *, with_spread: Literal[True],
    ) -> PosesAndSpread: ...

    def predict(
        self,
        variants: Sequence[Scene],
        steps: int,
        dt_steps: int = 1,
        every: int = 0,
        model: str = "",
        timeout_ms: int = 0,
        timeout: Optional[float] = None,
        *,
        with_spread: bool = False,
    ) -> Any:
        """Rolls every scene variant forward; returns ``[variants, frames, objects, 7]`` (the
        final frame only unless ``every`` > 0). Arguments and defaults as for
        :meth:`dynaserve.Client.predict`; ``timeout``: the call's deadline, seconds (default
        ``None``: the client's ``timeout``); ``with_spread`` (keyword only, default ``False``): return ``(poses, spread)``, the spread
        ``[variants, frames, objects, 2]`` float32 (``[position_m, orientation_deg]``, metres and
        degrees) or ``None`` when the model estimates none, as for
        :meth:`dynaserve.Client.predict`."""
        req = pb.PredictRequest(
            model=model,
            variants=[scene_pb(v, k) for k, v in enumerate(variants)],
            steps=steps,
            dt_steps=dt_steps,
            every=every,
            timeout_ms=timeout_ms,
        )
        return _trajectories(self._unary(self.world.Predict, req, timeout), with_spread)

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

    @overload
    def predict(
        self, steps: int, kinematic: Optional[Sequence[Mapping[int, npt.ArrayLike]]] = ...,
        poses: Optional[Sequence[Mapping[int, npt.ArrayLike]]] = ..., every: int = ..., timeout_ms: int = ...,
        timeout: Optional[float] = ...,
        *, with_spread: Literal[False] = ...,
    ) -> np.ndarray: ...

    @overload
    def predict(
        self, steps: int, kinematic: Optional[Sequence[Mapping[int, npt.ArrayLike]]] = ...,
        poses: Optional[Sequence[Mapping[int, npt.ArrayLike]]] = ..., every: int = ..., timeout_ms: int = ...,
        timeout: Optional[float] = ...,
        *, with_spread: Literal[True],
    ) -> PosesAndSpread: ...

    def predict(
        self,
        steps: int,
        kinematic: Optional[Sequence[Mapping[int, npt.ArrayLike]]] = None,
        poses: Optional[Sequence[Mapping[int, npt.ArrayLike]]] = None,
        every: int = 0,
        timeout_ms: int = 0,
        timeout: Optional[float] = None,
        *,
        with_spread: bool = False,
    ) -> Any:
        """Rolls variants of the session's state forward in one call; the session does not
        move. Variant ``i`` has its kinematic paths ``kinematic[i]`` and pose overrides
        ``poses[i]`` (``{index: [7]}``, at rest). Returns ``[variants, frames, objects, 7]``,
        or with ``with_spread`` ``(poses, spread)`` (spread ``[variants, frames, objects, 2]``
        or ``None``, as for :meth:`GrpcClient.predict`)."""
        req = spb.SessionPredictRequest(
            session_id=self.id,
            variants=_variants(kinematic, poses),
            steps=steps,
            every=every,
            timeout_ms=timeout_ms,
        )
        return _trajectories(self.client._unary(self.client.sessions.Predict, req, timeout), with_spread)

    def gradient(
        self,
        steps: int,
        kinematic: Sequence[Mapping[int, npt.ArrayLike]],
        cost: Any = None,
        every: int = 0,
        timeout_ms: int = 0,
        timeout: Optional[float] = None,
    ) -> Gradients:
        """Scores candidate paths ``kinematic[i]`` (``{index: [steps, 7]}``, every kinematic
        object) from the session's state by ``cost`` and differentiates the score; the
        session does not move. Returns :class:`~dynaserve.gradient.Gradients` (``cost``
        ``[candidates]``, ``translation`` and ``rotation`` ``[candidates, steps, kinematic,
        3]``). Arguments and defaults as for :meth:`dynaserve.Session.gradient`; ``timeout``:
        the call's deadline, seconds (default ``None``: the client's ``timeout``)."""
        req = _gradient_request(self.id, steps, kinematic, cost, every, timeout_ms)
        return _gradients(self.client._unary(self.client.sessions.Gradient, req, timeout))

    def interact(self, step_timeout: Optional[float] = None, timeout: Optional[float] = None) -> "Interaction":
        """A closed loop on this session (see :meth:`GrpcClient.interact`); the session keeps
        the state the loop leaves it in."""
        return self.client.interact(session_id=self.id, step_timeout=step_timeout, timeout=timeout)

    def delete(self) -> None:
        """Deletes the session on the server."""
        self.client._unary(self.client.sessions.DeleteSession, spb.DeleteSessionRequest(session_id=self.id))


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


__all__ = [
    "DEFAULT_STREAM_TIMEOUT",
    "DETAILS_KEY",
    "PUSHBACK_KEY",
    "SESSION_KEY",
    "AsyncFrameStream",
    "AsyncGrpcClient",
    "AsyncGrpcSession",
    "AsyncInteraction",
    "FrameStream",
    "GrpcClient",
    "GrpcSession",
    "Interaction",
    "Metadata",
    "Scene",
    "action_pb",
    "actions_pb",
    "error_of",
    "frame_of",
    "mesh_scene_pb",
    "model_info",
    "object_doc_pb",
    "object_spec",
    "object_state_pb",
    "pose_np",
    "pose_pb",
    "poses_np",
    "scene_pb",
]
