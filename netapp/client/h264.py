"""Encoding a robot's frames as H.264 (PyAV + libx264): each an `EncodedFrame` of one access unit, which every
H.264 transport carries (Socket.IO's `image_h264` event, wire-compatible with 5G-ERA; `frames`; RTP).

Low-latency settings: preset ultrafast, tune zerolatency, no B-frames, so every frame gives its packets at once
and the result's timestamp matches its frame; a keyframe at least every `keyint` frames (25 by default, option
"g"), so a netapp whose decoder had to reset recovers quickly. The caller drops frames before encoding, never
after: a lost packet would corrupt the remote decoder until the next keyframe.
"""

from __future__ import annotations

from fractions import Fraction
from typing import Any

import cv2
import numpy as np

from netapp.frame import H264, EncodedFrame

DEFAULT_OPTIONS = {"preset": "ultrafast", "tune": "zerolatency"}
DEFAULT_KEYFRAME_INTERVAL = 25
INSTALL_HINT = "the h264 transport needs PyAV: pip install 'netapp-toolkit[h264]'"


def require_av() -> Any:
    """The `av` module, or ImportError saying how to get it."""
    try:
        import av
    except ImportError as exc:
        raise ImportError(INSTALL_HINT) from exc
    return av


class H264Encoder:
    """A libx264 encoder for one frame size (yuv420p, as 5G-ERA's decoder expects)."""

    def __init__(self, width: int, height: int, options: dict[str, str] | None = None, fps: int = 30) -> None:
        av = require_av()
        if width % 2 or height % 2:
            raise ValueError(f"H.264 (yuv420p) needs an even width and height, got {width}x{height}")
        options = {**DEFAULT_OPTIONS, **(options or {})}
        self.keyframe_interval = int(options.pop("g", DEFAULT_KEYFRAME_INTERVAL))
        if self.keyframe_interval < 1:
            raise ValueError(f"the keyframe interval 'g' must be at least 1, got {self.keyframe_interval}")
        self.width, self.height = width, height
        ctx = av.CodecContext.create("libx264", "w")
        ctx.width, ctx.height, ctx.pix_fmt = width, height, "yuv420p"
        ctx.time_base = Fraction(1, fps)
        ctx.framerate = fps
        ctx.gop_size = self.keyframe_interval
        ctx.max_b_frames = 0  # B-frames would hold pictures back, and their results with them
        ctx.options = options
        ctx.open()
        self._ctx = ctx
        self._av = av
        self.frames = 0

    def takes(self, frame: np.ndarray) -> bool:
        """Whether `frame` has this encoder's size (another size needs a new stream)."""
        return frame.shape[:2] == (self.height, self.width)

    def encode(self, frame: np.ndarray) -> tuple[bytes, bool]:
        """A BGR frame -> (all its packets, whether they hold a keyframe)."""
        if self._ctx is None:
            raise ValueError("this H.264 encoder is closed")
        # OpenCV's BGR -> I420 (BT.601, video range, as swscale's default) takes a third of swscale's time.
        yuv = cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_BGR2YUV_I420)
        picture = self._av.VideoFrame.from_ndarray(yuv, format="yuv420p")
        picture.pts = self.frames
        self.frames += 1
        packets = self._ctx.encode(picture)
        return b"".join(bytes(p) for p in packets), any(p.is_keyframe for p in packets)

    def close(self) -> None:
        ctx, self._ctx = self._ctx, None
        close = getattr(ctx, "close", None)  # PyAV < 14; newer PyAV frees the context with its last reference
        if close is not None:
            close()


def encode_frame(
    encoder: H264Encoder | None, frame: np.ndarray, timestamp: int, options: dict[str, str] | None = None
) -> tuple[EncodedFrame | None, H264Encoder]:
    """One frame -> (its access unit with the picture's size, or None while the encoder holds it back; the encoder to
    reuse).

    `encoder` None, or one for another frame size, gives a new encoder: its stream starts with a keyframe.
    """
    if not isinstance(frame, np.ndarray) or frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
        raise ValueError("the h264 transport takes BGR uint8 frames of shape (height, width, 3)")
    height, width = frame.shape[:2]
    if encoder is None or (encoder.width, encoder.height) != (width, height):
        if encoder is not None:
            encoder.close()
        encoder = H264Encoder(width, height, options)
    data, _ = encoder.encode(frame)
    if not data:
        return None, encoder
    return EncodedFrame(H264, timestamp, data, width, height), encoder
