"""The asyncio client of the Dynaserve gRPC API (``grpc.aio``): :class:`AsyncGrpcClient`, its
frame streams, sessions and closed ``interact`` loop, the awaited counterparts of the
synchronous classes in :mod:`dynaserve.grpc`, which re-exports them (import them from there).
"""

from __future__ import annotations

import asyncio
from typing import Any, AsyncIterator, Callable, Dict, List, Literal, Mapping, Optional, Sequence, overload

import grpc
import grpc.aio
import numpy as np
import numpy.typing as npt

from .client import Frame, PosesAndSpread
from .errors import DynaserveError, warn_out_of_range
from .gradient import Gradients
from .grpc_base import DEFAULT_STREAM_TIMEOUT, _Base, _SessionFields
from .grpc_convert import (
    SESSION_KEY,
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
    actions_pb,
    error_of,
    frame_of,
    model_info,
    scene_pb,
)
from .mesh import Collector, Generated, MeshObject, checked_objects
from .v1 import sessions_pb2 as spb
from .v1 import world_model_pb2 as pb


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

    @overload
    async def predict(
        self, variants: Sequence[Scene], steps: int, dt_steps: int = ..., every: int = ..., model: str = ...,
        timeout_ms: int = ..., timeout: Optional[float] = ...,
        *, with_spread: Literal[False] = ...,
    ) -> np.ndarray: ...

    @overload
    async def predict(
        self, variants: Sequence[Scene], steps: int, dt_steps: int = ..., every: int = ..., model: str = ...,
        timeout_ms: int = ..., timeout: Optional[float] = ...,
        *, with_spread: Literal[True],
    ) -> PosesAndSpread: ...

    async def predict(
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
        """See :meth:`GrpcClient.predict`; ``[variants, frames, objects, 7]``, or with
        ``with_spread`` ``(poses, spread [variants, frames, objects, 2] or None)``."""
        req = pb.PredictRequest(
            model=model,
            variants=[scene_pb(v, k) for k, v in enumerate(variants)],
            steps=steps,
            dt_steps=dt_steps,
            every=every,
            timeout_ms=timeout_ms,
        )
        return _trajectories(await self._unary(self.world.Predict, req, timeout), with_spread)

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

    @overload
    async def predict(
        self, steps: int, kinematic: Optional[Sequence[Mapping[int, npt.ArrayLike]]] = ...,
        poses: Optional[Sequence[Mapping[int, npt.ArrayLike]]] = ..., every: int = ..., timeout_ms: int = ...,
        timeout: Optional[float] = ...,
        *, with_spread: Literal[False] = ...,
    ) -> np.ndarray: ...

    @overload
    async def predict(
        self, steps: int, kinematic: Optional[Sequence[Mapping[int, npt.ArrayLike]]] = ...,
        poses: Optional[Sequence[Mapping[int, npt.ArrayLike]]] = ..., every: int = ..., timeout_ms: int = ...,
        timeout: Optional[float] = ...,
        *, with_spread: Literal[True],
    ) -> PosesAndSpread: ...

    async def predict(
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
        """See :meth:`GrpcSession.predict`; ``[variants, frames, objects, 7]``, or with
        ``with_spread`` ``(poses, spread [variants, frames, objects, 2] or None)``."""
        req = spb.SessionPredictRequest(
            session_id=self.id,
            variants=_variants(kinematic, poses),
            steps=steps,
            every=every,
            timeout_ms=timeout_ms,
        )
        return _trajectories(await self.client._unary(self.client.sessions.Predict, req, timeout), with_spread)

    async def gradient(
        self,
        steps: int,
        kinematic: Sequence[Mapping[int, npt.ArrayLike]],
        cost: Any = None,
        every: int = 0,
        timeout_ms: int = 0,
        timeout: Optional[float] = None,
    ) -> Gradients:
        """See :meth:`GrpcSession.gradient`."""
        req = _gradient_request(self.id, steps, kinematic, cost, every, timeout_ms)
        return _gradients(await self.client._unary(self.client.sessions.Gradient, req, timeout))

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
