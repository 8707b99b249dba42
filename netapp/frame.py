"""What a frame is, on both sides of every wire: one encoded picture with its timing.

The robot's encoders make an `EncodedFrame`; each transport turns it into its own wire format at its edge only (the
5G-ERA Socket.IO dict, the `frames` binary message, an HTTP body, RTP packets) and the netapp's edges turn what they
read back into one, which its decoders take. Nothing here does I/O or imports either side.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

JPEG = "jpeg"
H264 = "h264"
CODEC_NAMES = (JPEG, H264)


@dataclass(frozen=True, slots=True)
class EncodedFrame:
    """One encoded frame: what it is (codec, bytes, picture size) and when (timestamp, deadline), plus the small
    metadata that travels with it (the robot's latency report, the W3C trace context)."""

    codec: str  # JPEG or H264
    timestamp: int  # the robot's stamp (ns since the epoch); a result carries it back
    payload: bytes  # a JPEG, or one H.264 access unit
    width: int = 0  # H.264: the picture size its decoder opens with (0: as before); 0 for a JPEG
    height: int = 0
    deadline_ms: float | None = None  # its result must leave the netapp within this long of its receipt; None: none
    meta: dict[str, Any] | None = None  # small, JSON-able; bounded by each wire's edge

    @property
    def size(self) -> int:
        """What it weighs on the wire (its payload)."""
        return len(self.payload)

    def with_meta(self, **fields: Any) -> EncodedFrame:
        """The same frame with `fields` added to its metadata (None values left out)."""
        added = {k: v for k, v in fields.items() if v is not None}
        return replace(self, meta={**(self.meta or {}), **added}) if added else self
