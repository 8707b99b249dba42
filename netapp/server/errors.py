"""What can happen to a frame besides a result: each reaches its sender with a clear message.

Each carries its HTTP status and a stable `reason` code, so the HTTP transport maps all of them in one place.
"""

from __future__ import annotations

from netapp.protocol import DEADLINE_REASON


class FrameError(Exception):
    """A frame that got no result: `reason` labels the metric and the error body, `status` the HTTP reply."""

    status = 500
    reason = "error"


class FrameRejected(FrameError):
    """Input the server will not take."""

    def __init__(self, reason: str, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.reason = reason
        self.status = status


class FrameDropped(FrameError):
    """A newer frame of the same robot superseded this one before it was processed."""

    status = 409
    reason = "superseded"

    def __init__(self, message: str = "frame superseded by a newer frame of this session (newest frame wins)") -> None:
        super().__init__(message)


class SessionsFull(Exception):
    """The netapp holds as many sessions as it may: the lower of its session cap (`Settings.max_sessions`) and its
    measured capacity's hard limit (`netapp.server.capacity`)."""

    retry_after_s = 5

    def __init__(self, limit: int, why: str) -> None:
        super().__init__(
            f"this netapp already serves its limit of {limit} sessions ({why}): retry in {self.retry_after_s} s, "
            "or ask the middleware for another netapp"
        )
        self.limit = limit


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
