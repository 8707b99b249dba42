"""What the netapp answers instead of what was asked: each reaches its sender with a clear message.

The dataplane raises these; each carries its HTTP status, a stable `reason` code and, for a 503, when to try again,
so each transport maps all of them in one place: HTTP's error body (`netapp.server.http.errors`), every push
transport's error event (`ServingError.event`) and the command acknowledgements (`refusal_fields`).
"""

from __future__ import annotations

from typing import Any

from netapp.protocol import DEADLINE_REASON, DRAINING_REASON, SESSIONS_FULL_REASON, SUPERSEDED_REASON, error_event


class ServingError(Exception):
    """An error answer: `status` (HTTP), `reason` (a stable code for the metric and the error body), the message
    (what to do), `retry_after_s` (when a robot may try again, if it may) and `details` (more for the error body)."""

    status = 500
    reason = "error"

    @property
    def retry_after_s(self) -> int | None:
        return None

    @property
    def details(self) -> dict[str, Any]:
        return {}

    def event(self, timestamp: int | None) -> dict[str, Any]:
        """This error as the error event of the frame stamped `timestamp` (`netapp.protocol.error_event`)."""
        return error_event(timestamp, str(self), self.reason)


class RequestRefused(ServingError):
    """A request (not a frame) the netapp will not serve: a session it cannot open or find, a state command."""

    def __init__(
        self, reason: str, message: str, status: int = 400, *, retry_after_s: int | None = None, **details: Any
    ) -> None:
        super().__init__(message)
        self.reason = reason
        self.status = status
        self._retry_after_s = retry_after_s
        self._details = details

    @property
    def retry_after_s(self) -> int | None:
        return self._retry_after_s

    @property
    def details(self) -> dict[str, Any]:
        return self._details


def draining(message: str) -> RequestRefused:
    """503 `draining`: this replica is going away; the robot goes on through the Service after Retry-After."""
    return RequestRefused(DRAINING_REASON, message, 503, retry_after_s=1)


class FrameError(ServingError):
    """A frame that got no result: `reason` labels the metric and the error body, `status` the HTTP reply."""

    @property
    def retry_after_s(self) -> int | None:
        return 1 if self.status == 503 else None  # draining, not ready, too many waiting: a moment later


class FrameRejected(FrameError):
    """Input the server will not take; `retry_after_s` for a 503 that knows better than a moment later (the load)."""

    def __init__(self, reason: str, message: str, status: int = 400, *, retry_after_s: int | None = None) -> None:
        super().__init__(message)
        self.reason = reason
        self.status = status
        self._retry_after_s = retry_after_s

    @property
    def retry_after_s(self) -> int | None:
        return self._retry_after_s if self._retry_after_s is not None else super().retry_after_s


class FrameDropped(FrameError):
    """A newer frame of the same robot superseded this one before it was processed."""

    status = 409
    reason = SUPERSEDED_REASON

    def __init__(self, message: str = "frame superseded by a newer frame of this session (newest frame wins)") -> None:
        super().__init__(message)


class SessionsFull(ServingError):
    """The netapp holds as many sessions as it may: the lower of its session cap (`Settings.max_sessions`) and its
    measured capacity's hard limit (`netapp.server.capacity`); `retry_after_s`, when the next session is expected to
    end (`netapp.server.retry_after`)."""

    status = 503
    reason = SESSIONS_FULL_REASON

    def __init__(self, limit: int, why: str, retry_after_s: int) -> None:
        super().__init__(
            f"this netapp already serves its limit of {limit} sessions ({why}): retry in {retry_after_s} s, "
            "or ask the middleware for another netapp"
        )
        self.limit = limit
        self._retry_after_s = retry_after_s

    @property
    def retry_after_s(self) -> int:
        return self._retry_after_s

    @property
    def details(self) -> dict[str, Any]:
        return {"limit": self.limit}


def refusal_fields(error: ServingError) -> dict[str, Any]:
    """What a program reads of a refusal beside its message: `reason`, `retry_after_s` (if any) and the details
    (the Socket.IO command_error; HTTP carries the same in its error body and Retry-After header)."""
    retry = error.retry_after_s
    return {"reason": error.reason, **({"retry_after_s": retry} if retry is not None else {}), **error.details}


class SessionClosed(FrameError):
    """The session ended while its frame waited."""

    status = 410
    reason = "session_closed"


class DeadlineMissed(FrameError):
    """The frame could not be finished within its robot's deadline, so no inference was spent on it."""

    status = 504
    reason = DEADLINE_REASON

    def __init__(self, deadline_ms: float, waited_ms: float, expected_ms: float) -> None:
        super().__init__(
            f"dropped before inference: it could not finish within its {deadline_ms:g} ms deadline "
            f"(it had waited {waited_ms:.0f} ms, processing takes about {expected_ms:.0f} ms)"
        )


class ResultTimeout(FrameError):
    """A robot waiting for its frame's result (HTTP `?wait=true`) waited longer than the netapp lets it."""

    status = 504
    reason = "timeout"

    def __init__(self, timeout_s: float) -> None:
        super().__init__(f"no result within {timeout_s} s")
