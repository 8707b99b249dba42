"""The `frames` transport's wire format (docs/protocol.md), shared by the netapp and the robot client (no server code).

One plain WebSocket per robot session at `FRAMES_PATH`. Frames go robot -> netapp as binary messages: a fixed
20-byte header, an optional small JSON part (the robot's latency report), then the encoded frame (a JPEG, or an
H.264 access unit). Everything else is a text message holding one JSON object: robot -> netapp the 5G-ERA commands
(INIT, the state commands) with an `id` their acknowledgement repeats; netapp -> robot events named by `event`
(`ack`, `results`, `error`, `session_info`, `move`, `refused`).
"""

from __future__ import annotations

import struct
from typing import Any
from urllib.parse import urlsplit

from netapp import wire_json
from netapp.frame import H264, JPEG, EncodedFrame
from netapp.protocol import parse_deadline_ms

FRAMES_PATH = "/frames"


def frames_url(url: str) -> str:
    """The netapp's http(s) URL -> its frames WebSocket's ws(s) URL."""
    parts = urlsplit(url)
    scheme = "wss" if parts.scheme == "https" else "ws"
    return f"{scheme}://{parts.netloc}{parts.path.rstrip('/')}{FRAMES_PATH}"


# The header of a frame message, little-endian: kind, codec, length of the JSON part, picture width and height
# (H.264: the size its decoder opens with; 0 = as before, or a JPEG), deadline (ms, float32; 0 = none), timestamp (ns).
HEADER = struct.Struct("<BBHHHfq")
KIND_FRAME = 1
CODECS = {JPEG: 1, H264: 2}  # codec name -> its byte in the header
CODEC_NAMES = {code: name for name, code in CODECS.items()}
MAX_META_BYTES = 4096  # the JSON part (a latency report is about 100 bytes)
# Netapp -> robot events (the `event` key of a text message).
ACK_EVENT = "ack"  # a command's acknowledgement: {"id", "ok", "message"} and, refused, the refusal's fields
ERROR_EVENT = "error"  # {"data": {"timestamp", "error", "reason"}}: a frame's error, or a bad message
# and, named as on Socket.IO (netapp.protocol): RESULTS_EVENT {"data": a result message}; SESSION_INFO_EVENT
# {"data": {...}} just before INIT's ack (docs/server.md#input-size); MOVE_EVENT {"data": {"reason", "message"}}:
# this replica is going away, reconnect through the Service.
REFUSED_EVENT = "refused"  # {"data": error body}: the connection is refused (token, draining); it is closed next
# WebSocket close codes the netapp uses (RFC 6455): the reason text says why.
CLOSE_POLICY = 1008  # no or a wrong token
CLOSE_TRY_AGAIN = 1013  # draining: connect again through the Service


class WireError(ValueError):
    """A message that does not follow the format: `reason` is the stable code its error event carries."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


def pack_frame(frame: EncodedFrame) -> bytes:
    """A frame -> its binary message (the robot's side)."""
    part = wire_json.dumpb(frame.meta) if frame.meta else b""
    header = HEADER.pack(
        KIND_FRAME, CODECS[frame.codec], len(part), frame.width, frame.height, frame.deadline_ms or 0.0, frame.timestamp
    )
    return b"".join((header, part, frame.payload))


def parse_frame(data: bytes) -> EncodedFrame:
    """A binary message -> its frame; WireError saying what is wrong (checked before anything is copied)."""
    if len(data) < HEADER.size:
        raise WireError("truncated", f"a frame message starts with a {HEADER.size}-byte header, got {len(data)} bytes")
    kind, code, meta_len, width, height, deadline, timestamp = HEADER.unpack_from(data)
    if kind != KIND_FRAME:
        raise WireError("unknown_kind", f"unknown message kind {kind} (a frame is {KIND_FRAME})")
    codec = CODEC_NAMES.get(code)
    if codec is None:
        raise WireError("bad_codec", f"unknown codec {code} (known: {CODECS})")
    if meta_len > MAX_META_BYTES or HEADER.size + meta_len > len(data):
        raise WireError("bad_meta", f"a JSON part of {meta_len} bytes: at most {MAX_META_BYTES}, within the message")
    try:
        deadline_ms = parse_deadline_ms(deadline or None)  # 0: none; NaN, negative or too long: refused
    except ValueError as exc:
        raise WireError("bad_deadline", str(exc)) from None
    meta = None
    if meta_len:
        try:
            meta = wire_json.loads(data[HEADER.size : HEADER.size + meta_len])  # UTF-8 or refused
        except ValueError as exc:
            raise WireError("bad_meta", f"the JSON part is not JSON: {exc}") from None
        if not isinstance(meta, dict):
            raise WireError("bad_meta", f"the JSON part must be an object, got {type(meta).__name__}")
    payload = data[HEADER.size + meta_len :]
    return EncodedFrame(codec, timestamp, payload, width, height, deadline_ms, meta)


def read_event(text: Any) -> tuple[str, dict[str, Any]] | None:
    """A netapp -> robot text message as (its event's name, the message); None for anything else: binary, not JSON,
    not an event (a hostile or broken peer)."""
    try:
        message = wire_json.loads(text) if isinstance(text, str) else None
    except ValueError:
        return None
    if not isinstance(message, dict) or not isinstance(message.get("event"), str):
        return None
    return message["event"], message


def event(name: str, data: Any = None, **fields: Any) -> str:
    """A netapp -> robot text message."""
    return wire_json.dumps({"event": name, **({"data": data} if data is not None else {}), **fields})


def parse_text(text: str, max_bytes: int) -> dict[str, Any]:
    """A text message -> its JSON object; WireError when it is none (or longer than `max_bytes`)."""
    if len(text) > max_bytes:
        raise WireError("too_large", f"a text message of {len(text)} characters is over the {max_bytes} limit")
    try:
        message = wire_json.loads(text)
    except ValueError as exc:
        raise WireError("malformed", f"a text message must be one JSON object: {exc}") from None
    if not isinstance(message, dict):
        raise WireError("malformed", f"a text message must be one JSON object, got {type(message).__name__}")
    return message
