"""Errors raised by the client: one exception type carrying the server's error document."""

from __future__ import annotations

import warnings
from typing import Iterable, Optional

WARNING_HEADER = "x-dynaserve-warning"


class DynaserveError(Exception):
    """A request the server refused or failed.

    Attributes:
        status: HTTP status (422 invalid input, 404 unknown session, 400 a call the model
            cannot serve (``FAILED_PRECONDITION``: gradients from a model without them), 429
            overload, 503 unavailable, 504 deadline exceeded, 500 internal); over gRPC, the
            status the HTTP API gives the same error (499 for a cancelled call).
        code: gRPC-style code name, e.g. ``INVALID_ARGUMENT`` or ``NOT_FOUND``.
        field: path of the offending field for invalid input, e.g.
            ``actions[3].kinematic[0].pose.rotation`` (over gRPC read from the status's
            ``google.rpc.BadRequest`` detail); ``None`` otherwise.
        retry_after_ms: suggested wait before retrying (overload only).
    """

    def __init__(
        self,
        status: int,
        code: str,
        message: str,
        field: Optional[str] = None,
        retry_after_ms: Optional[int] = None,
    ) -> None:
        super().__init__(f"{code} ({status}): {message}")
        self.status = status
        self.code = code
        self.message = message
        self.field = field
        self.retry_after_ms = retry_after_ms


class OutOfRangeWarning(UserWarning):
    """The server answered, but some object's mass, friction or restitution lies outside the
    range its model was trained on, so the forecast there is less accurate. The message names
    the objects and the trained range (the server's ``x-dynaserve-warning`` header or gRPC
    metadata). Turn it into an error with ``warnings.simplefilter("error", OutOfRangeWarning)``.
    """


class BodyFrameWarning(UserWarning):
    """A :class:`~dynaserve.Body`'s points look like a world-frame cloud: their centroid lies
    far (over 10% of the cloud's extent and over 1 cm) from the body-frame origin, which is
    the centre of mass. The server would take them as given, with other dynamics than meant;
    :meth:`Body.from_world_points <dynaserve.Body.from_world_points>` makes the body from such
    a cloud."""


def warn_out_of_range(pairs: Iterable[tuple]) -> None:
    """Issues one :class:`OutOfRangeWarning` per ``x-dynaserve-warning`` entry of ``pairs``
    (header or metadata ``(key, value)`` pairs)."""
    for key, value in pairs:
        if key.lower() == WARNING_HEADER:
            text = value.decode() if isinstance(value, bytes) else str(value)
            warnings.warn(text, OutOfRangeWarning, stacklevel=4)
