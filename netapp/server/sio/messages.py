"""The 5G-ERA frame message (Socket.IO's `image` and `image_h264` events), checked and converted to the one frame
type (`netapp.frame.EncodedFrame`) at Socket.IO's edge, before anything is decoded."""

from __future__ import annotations

from typing import Any

from netapp.frame import H264, EncodedFrame
from netapp.protocol import DEADLINE_FIELD, parse_deadline_ms
from netapp.server.errors import FrameRejected

METADATA_FIELD = "metadata"  # 5G-ERA's free-form mapping: the robot's latency report, the W3C trace context


def frame_from_message(message: Any, codec: str, max_bytes: int) -> EncodedFrame:
    """The 5G-ERA image message -> its frame: {"timestamp": int, "frame": bytes, "metadata": {...}}, and for H.264
    "width" and "height" (the size its decoder opens with; absent: as before); FrameRejected saying what is wrong."""
    deadline_ms = validate_frame_message(message, max_bytes)
    width = height = 0
    if codec == H264:  # a JPEG carries its own size; 5G-ERA's JPEG messages may say any
        width, height = (_side(message, name) for name in ("width", "height"))
    metadata = message.get(METADATA_FIELD)
    meta = metadata if isinstance(metadata, dict) and metadata else None  # bounded by the transport's packet limit
    return EncodedFrame(codec, message["timestamp"], message["frame"], width, height, deadline_ms, meta)


def _side(message: dict[str, Any], name: str) -> int:
    """An H.264 message's width or height: an integer (its range checked by the decoder), 0 where absent."""
    value = message.get(name)
    if value is None:
        return 0
    if not isinstance(value, int) or isinstance(value, bool):
        raise FrameRejected("bad_size", f"H.264 frame '{name}' must be an integer, got {value!r}")
    return value


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
