"""What the synchronous and asyncio gRPC clients (:mod:`dynaserve.grpc`,
:mod:`dynaserve.grpc_async`) are both built on: the default stream deadline, the channel a client
opens with its deadlines and call metadata (``_Base``), and what a session object knows of its
session (``_SessionFields``).
"""

from __future__ import annotations

import secrets
from typing import Any, List, Optional, Union

import grpc

from .client import AFFINITY_HEADER
from .grpc_convert import Metadata, _target
from .v1 import sessions_pb2 as spb
from .v1 import sessions_pb2_grpc, world_model_pb2_grpc

DEFAULT_STREAM_TIMEOUT = 600.0
"""Whole-call deadline of streaming calls (Rollout, session Step, Generate), seconds."""


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
