"""What the robot puts on the wire, settable while it streams: `NetAppClient.set_send_settings` (the one knob an
adaptive controller turns). Each frame is sent with the settings in force when it goes on the wire."""

from __future__ import annotations

from dataclasses import dataclass

MIN_LONG_SIDE = 32  # a cap below this leaves a detector nothing to see
MAX_JPEG_QUALITY = 100


@dataclass(frozen=True)
class SendSettings:
    """`long_side`: the most pixels on the long side of a sent frame (aspect ratio kept; None: no cap beyond what
    the netapp's processor uses, `docs/client.md#what-is-sent`). `jpeg_quality`: 1..100 for JPEG frames.
    `bitrate_kbps`: the H.264 target bitrate (None: libx264's constant quality); it changes in place where libx264
    allows it, else with a new stream (`netapp.client.h264`), as a size change does. `codec`: "jpeg" or "h264" on a
    transport that carries both, when the uplink adapts (None: the transport's own). `fps`: the frame rate the H.264
    bitrate is spread over (the adapter's chosen rate; None: the rate measured from the frames)."""

    long_side: int | None = None
    jpeg_quality: int = 85
    bitrate_kbps: int | None = None
    codec: str | None = None
    fps: float | None = None

    def __post_init__(self) -> None:
        if self.long_side is not None and (isinstance(self.long_side, bool) or self.long_side < MIN_LONG_SIDE):
            raise ValueError(f"long_side must be at least {MIN_LONG_SIDE} pixels (or None), got {self.long_side!r}")
        if isinstance(self.jpeg_quality, bool) or not 1 <= self.jpeg_quality <= MAX_JPEG_QUALITY:
            raise ValueError(f"jpeg_quality must be in 1..{MAX_JPEG_QUALITY}, got {self.jpeg_quality!r}")
        if self.bitrate_kbps is not None and (isinstance(self.bitrate_kbps, bool) or self.bitrate_kbps < 1):
            raise ValueError(f"bitrate_kbps must be a positive number of kbit/s (or None), got {self.bitrate_kbps!r}")
        if self.fps is not None and (isinstance(self.fps, bool) or not self.fps > 0):
            raise ValueError(f"fps must be a positive frame rate (or None), got {self.fps!r}")
        if self.codec not in (None, "jpeg", "h264"):
            raise ValueError(f"codec must be jpeg or h264 (or None), got {self.codec!r}")
