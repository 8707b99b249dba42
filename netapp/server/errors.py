"""What can happen to a frame besides a result: each reaches its sender with a clear message."""

from __future__ import annotations


class FrameRejected(Exception):
    """Input the server will not take; `reason` labels the metric and the error message, `status` the HTTP reply."""

    def __init__(self, reason: str, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.reason = reason
        self.status = status


class FrameDropped(Exception):
    """A newer frame of the same robot superseded this one before it was processed."""


class SessionClosed(Exception):
    """The session ended while its frame waited."""
