"""The 5G-ERA frame message, checked before anything is decoded."""

from __future__ import annotations

from typing import Any

from netapp.protocol import DEADLINE_FIELD, parse_deadline_ms
from netapp.server.errors import FrameRejected


def validate_frame_message(message: Any, max_bytes: int) -> float | None:
    """The 5G-ERA image message: {"timestamp": int, "frame": bytes, ...}, and our optional `deadline_ms`, which it
    returns; FrameRejected saying what is wrong."""
    if not isinstance(message, dict):
        raise FrameRejected(
            "malformed", f"expected a mapping with 'timestamp' and 'frame', got {type(message).__name__}"
        )
    timestamp = message.get("timestamp")
    if timestamp is None:
        raise FrameRejected("missing_timestamp", "missing 'timestamp' (int, nanoseconds): it keys the result")
    if not isinstance(timestamp, int) or isinstance(timestamp, bool):
        raise FrameRejected("bad_timestamp", f"'timestamp' must be an integer, got {type(timestamp).__name__}")
    frame = message.get("frame")
    if frame is None:
        raise FrameRejected("missing_frame", "missing 'frame' (bytes)")
    if not isinstance(frame, (bytes, bytearray)):
        raise FrameRejected("bad_frame", f"'frame' must be binary, got {type(frame).__name__}")
    if len(frame) > max_bytes:
        raise FrameRejected("payload_too_large", f"frame of {len(frame)} bytes is over the {max_bytes}-byte limit")
    try:
        return parse_deadline_ms(message.get(DEADLINE_FIELD))
    except ValueError as exc:
        raise FrameRejected("bad_deadline", str(exc)) from exc
