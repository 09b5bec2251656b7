"""Synchronous and asyncio clients of the Dynaserve HTTP API (standard library HTTP, numpy
arrays in and out).

Poses are ``[objects, 7]`` arrays (``[x, y, z, qx, qy, qz, qw]``), trajectories
``[frames, objects, 7]``. Every failure raises :class:`~dynaserve.errors.DynaserveError` with
the server's code, message and field path.

Scale-out: every call carries the ``x-dynaserve-affinity`` header (one random key per client
unless given), so that a gateway hashing it sends all calls of a session and of its forks to
the replica that holds them.
"""

from __future__ import annotations

import asyncio
import http.client
import json
import secrets
import urllib.parse
from dataclasses import dataclass
from typing import Any, Dict, Iterator, List, Optional, Sequence

import numpy as np

from .errors import DynaserveError, warn_out_of_range
from .scene import Body, actions_doc, object_state_doc, poses_array, scene_doc

AFFINITY_HEADER = "x-dynaserve-affinity"


@dataclass
class Frame:
    """The state after one step: ``poses`` ``[objects, 7]`` at ``time`` seconds (step ``step``,
    counted from 1; within a session from the session's start)."""

    step: int
    time: float
    poses: np.ndarray


def _frame(doc: Dict[str, Any]) -> Frame:
    return Frame(step=int(doc["step"]), time=float(doc["time"]), poses=poses_array(doc["poses"]))


def _scene(scene: Any) -> Dict[str, Any]:
    """A scene given as bodies or as a ready JSON document."""
    if isinstance(scene, dict):
        return scene
    return scene_doc(list(scene))


class Client:
    """A client of one server, e.g. ``Client("http://127.0.0.1:8080")``.

    Args:
        base_url: the server's HTTP address.
        timeout: socket timeout per call, seconds.
        affinity: the gateway routing key sent with every call (random when ``None``).
        token: optional bearer token.
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
        self.timeout = timeout
        self.affinity = affinity or secrets.token_hex(8)
        self._token = token
        self.last_request_bytes = 0

    # ---- transport ----

    def _conn(self) -> http.client.HTTPConnection:
        cls = http.client.HTTPSConnection if self._https else http.client.HTTPConnection
        return cls(self._host, self._port, timeout=self.timeout)

    def _headers(self, extra: Optional[Dict[str, str]] = None) -> Dict[str, str]:
        h = {"content-type": "application/json", AFFINITY_HEADER: self.affinity}
        if self._token:
            h["authorization"] = f"Bearer {self._token}"
        h.update(extra or {})
        return h

    def request(self, method: str, path: str, body: Optional[Dict[str, Any]] = None) -> Any:
        """Sends one request and returns the decoded JSON answer (``None`` for 204)."""
        data = json.dumps(body).encode() if body is not None else None
        self.last_request_bytes = len(data or b"")
        conn = self._conn()
        try:
            conn.request(method, path, body=data, headers=self._headers())
            resp = conn.getresponse()
            raw = resp.read()
        finally:
            conn.close()
        if resp.status >= 400:
            raise _error(resp.status, raw)
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
        """Rolls a scene (bodies or a ``Scene`` document) forward and yields every frame as
        the server streams it (Server-Sent Events)."""
        body = {
            "model": model,
            "scene": _scene(scene),
            "steps": steps,
            "dt_steps": dt_steps,
            "timeout_ms": timeout_ms,
        }
        conn = self._conn()
        try:
            conn.request(
                "POST",
                "/v1/rollout",
                body=json.dumps(body).encode(),
                headers=self._headers({"accept": "text/event-stream"}),
            )
            resp = conn.getresponse()
            if resp.status >= 400:
                raise _error(resp.status, resp.read())
            warn_out_of_range(resp.getheaders())
            event, data = "", []
            for line in resp:
                text = line.decode().rstrip("\r\n")
                if text.startswith("event:"):
                    event = text[6:].strip()
                elif text.startswith("data:"):
                    data.append(text[5:].strip())
                elif text == "" and data:
                    payload = json.loads("\n".join(data))
                    if event == "frame":
                        yield _frame(payload)
                    elif event == "error":
                        e = payload["error"]
                        raise DynaserveError(
                            200, e["code"], e["message"], e.get("field"), e.get("retry_after_ms")
                        )
                    elif event == "done":
                        return
                    event, data = "", []
        finally:
            conn.close()

    def predict(
        self,
        variants: Sequence[Any],
        steps: int,
        dt_steps: int = 1,
        every: int = 0,
        model: str = "",
        timeout_ms: int = 0,
    ) -> np.ndarray:
        """Rolls every scene variant forward; returns ``[variants, frames, objects, 7]``
        (the final frame only unless ``every`` > 0)."""
        out = self.request(
            "POST",
            "/v1/predict",
            {
                "model": model,
                "variants": [_scene(v) for v in variants],
                "steps": steps,
                "dt_steps": dt_steps,
                "every": every,
                "timeout_ms": timeout_ms,
            },
        )
        return _trajectories(out)

    # ---- sessions ----

    def create_session(
        self,
        scene: Any,
        kinematic: Sequence[int] = (),
        dt_steps: int = 1,
        model: str = "",
    ) -> "Session":
        """Sends a scene once and keeps it on the server with its state; ``kinematic`` lists
        the objects whose poses the caller gives every step."""
        info = self.request(
            "POST",
            "/v1/sessions",
            {
                "model": model,
                "scene": _scene(scene),
                "dt_steps": dt_steps,
                "kinematic": list(kinematic),
            },
        )
        return Session(self, info)


def _trajectories(out: Dict[str, Any]) -> np.ndarray:
    return np.stack(
        [np.stack([poses_array(f["poses"]) for f in t["frames"]]) for t in out["trajectories"]]
    )


def _error(status: int, raw: bytes) -> DynaserveError:
    try:
        e = json.loads(raw)["error"]
        return DynaserveError(status, e["code"], e["message"], e.get("field"), e.get("retry_after_ms"))
    except (ValueError, KeyError, TypeError):
        return DynaserveError(status, "UNKNOWN", raw.decode(errors="replace"))


class Session:
    """A scene kept on the server with its state. Kinematic paths are ``{object index:
    [steps, 7] poses}``: each kinematic object's pose at the end of every step."""

    def __init__(self, client: Client, info: Dict[str, Any]) -> None:
        self.client = client
        self.id: str = info["session_id"]
        self.model: str = info["model"]
        self.objects: int = int(info["objects"])
        self.dt_steps: int = int(info["dt_steps"])
        self.kinematic: List[int] = list(info.get("kinematic", []))
        self.expires_at_unix_ms: int = int(info["expires_at_unix_ms"])

    @property
    def _path(self) -> str:
        return f"/v1/sessions/{self.id}"

    def step(
        self,
        steps: int,
        kinematic: Optional[Dict[int, np.ndarray]] = None,
        timeout_ms: int = 0,
    ) -> List[Frame]:
        """Advances the session; returns one frame per step."""
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
        poses: Dict[int, Sequence[float]],
        velocities: Optional[Dict[int, Sequence[float]]] = None,
    ) -> Dict[str, Any]:
        """Overwrites the listed objects' poses ``{index: [7]}`` (at rest, or with velocities
        ``{index: [6]}``), e.g. from an observation; returns the new state."""
        velocities = velocities or {}
        body = {"objects": [object_state_doc(j, p, velocities.get(j)) for j, p in poses.items()]}
        return _state(self.client.request("PUT", f"{self._path}/state", body))

    def fork(self) -> "Session":
        """A copy of this session (same scene, its own state) under a new id."""
        return Session(self.client, self.client.request("POST", f"{self._path}/fork"))

    def predict(
        self,
        steps: int,
        kinematic: Optional[Sequence[Dict[int, np.ndarray]]] = None,
        poses: Optional[Sequence[Dict[int, Sequence[float]]]] = None,
        every: int = 0,
        timeout_ms: int = 0,
    ) -> np.ndarray:
        """Rolls variants of the session's state forward in one call; the session does not
        move. Variant ``i`` has its kinematic paths ``kinematic[i]`` and pose overrides
        ``poses[i]`` (``{index: [7]}``, at rest). Returns ``[variants, frames, objects, 7]``."""
        n = max(len(kinematic or []), len(poses or []), 1)
        variants = []
        for i in range(n):
            v: Dict[str, Any] = {}
            if kinematic:
                v["actions"] = actions_doc(kinematic[i])
            if poses:
                v["state"] = [object_state_doc(j, p) for j, p in poses[i].items()]
            variants.append(v)
        out = self.client.request(
            "POST",
            f"{self._path}/predict",
            {"variants": variants, "steps": steps, "every": every, "timeout_ms": timeout_ms},
        )
        return _trajectories(out)

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

    async def predict(self, *args: Any, **kwargs: Any) -> np.ndarray:
        """See :meth:`Client.predict`."""
        return await asyncio.to_thread(self.sync.predict, *args, **kwargs)

    async def rollout(self, *args: Any, **kwargs: Any) -> List[Frame]:
        """See :meth:`Client.rollout`; returns the whole list of frames."""
        return await asyncio.to_thread(lambda: list(self.sync.rollout(*args, **kwargs)))

    async def create_session(self, *args: Any, **kwargs: Any) -> Session:
        """See :meth:`Client.create_session` (the session's own methods are blocking; wrap
        them with ``asyncio.to_thread``)."""
        return await asyncio.to_thread(self.sync.create_session, *args, **kwargs)
