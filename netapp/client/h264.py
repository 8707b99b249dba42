"""Encoding a robot's frames as H.264 (PyAV + libx264): each an `EncodedFrame` of one access unit, which every
H.264 transport carries (Socket.IO's `image_h264` event, wire-compatible with 5G-ERA; `frames`; RTP).

Low-latency settings: preset ultrafast, tune zerolatency, no B-frames, so every frame gives its packets at once
and the result's timestamp matches its frame; a keyframe at least every `keyint` frames (25 by default, option
"g"), so a netapp whose decoder had to reset recovers quickly. The caller drops frames before encoding, never
after: a lost packet would corrupt the remote decoder until the next keyframe.

With a bitrate (`H264Encoder(bitrate_kbps=...)`) libx264 runs its average bitrate under a VBV whose buffer holds
`VBV_FRAMES` frames' bytes: no frame, a keyframe included, takes more than that, so a keyframe never blows a frame's
budget by more (its quality gives way instead), and a new stream's first one takes about one frame's (`VBV_INIT`).
The bitrate then changes in place (`set_bitrate`: PyAV 18 lets `bit_rate` change on an open encoder and libavcodec
reconfigures x264 at the next frame) up to the rate the stream was opened with; PyAV 18 cannot change the VBV's
maximum rate or buffer of an open encoder (`max_bit_rate` is read-only, `rc_buffer_size` absent), so a rise above it
needs a new stream. A keyframe is asked for in place too (`encode(..., keyframe=True)`: the picture typed I), the
cheap recovery when the netapp's decoder lost the stream.
"""

from __future__ import annotations

from fractions import Fraction
from typing import Any

import cv2
import numpy as np

from netapp.frame import H264, EncodedFrame

DEFAULT_OPTIONS = {"preset": "ultrafast", "tune": "zerolatency"}
DEFAULT_KEYFRAME_INTERVAL = 25
VBV_FRAMES = 1.5  # the VBV buffer, in frames' bytes at the bitrate: the most one frame (a keyframe too) may take
# A new stream's buffer starts this full (x264's default 0.9): its first keyframe, which follows a codec switch or a
# rise, when the uplink's queue is likeliest full, takes about 1.05 frames' bytes rather than 1.35 (at 0.25 Mbit/s
# 2.6 KB rather than 3.7: 83 ms on the wire rather than 118; measured on the shared clip at 256 px, 250 kbit/s)
VBV_INIT = 0.5
BITRATE_KEYFRAME_S = 10  # with a bitrate, a keyframe this seldom (each is a poor picture in a frame's bytes);
# a netapp whose decoder lost the stream asks for one sooner (`keyframe=True`)
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

    def __init__(
        self,
        width: int,
        height: int,
        options: dict[str, str] | None = None,
        fps: int = 30,
        bitrate_kbps: int | None = None,
    ) -> None:
        av = require_av()
        if width % 2 or height % 2:
            raise ValueError(f"H.264 (yuv420p) needs an even width and height, got {width}x{height}")
        options = {**DEFAULT_OPTIONS, **(options or {})}
        every = DEFAULT_KEYFRAME_INTERVAL if bitrate_kbps is None else BITRATE_KEYFRAME_S * fps
        self.keyframe_interval = int(options.pop("g", every))
        if self.keyframe_interval < 1:
            raise ValueError(f"the keyframe interval 'g' must be at least 1, got {self.keyframe_interval}")
        self.width, self.height = width, height
        self.fps = fps  # the rate the bitrate is spread over (the stream's time base), fixed while it lasts
        ctx = av.CodecContext.create("libx264", "w")
        ctx.width, ctx.height, ctx.pix_fmt = width, height, "yuv420p"
        ctx.time_base = Fraction(1, fps)
        ctx.framerate = fps
        ctx.gop_size = self.keyframe_interval
        ctx.max_b_frames = 0  # B-frames would hold pictures back, and their results with them
        self.bitrate_kbps = bitrate_kbps
        self.max_bitrate_kbps = bitrate_kbps  # the VBV's rate, fixed while the stream lasts
        if bitrate_kbps is not None:
            ctx.bit_rate = bitrate_kbps * 1000
            buffer_kbit = max(1, round(bitrate_kbps * VBV_FRAMES / fps))
            options = {**options, "maxrate": f"{bitrate_kbps}k", "bufsize": f"{buffer_kbit}k"}
            options.setdefault("x264-params", f"vbv-init={VBV_INIT}")  # a caller's own x264-params stand
        ctx.options = options
        ctx.open()
        self._ctx = ctx
        self._av = av
        self.frames = 0

    def takes(self, frame: np.ndarray) -> bool:
        """Whether `frame` has this encoder's size (another size needs a new stream)."""
        return frame.shape[:2] == (self.height, self.width)

    def set_bitrate(self, bitrate_kbps: int) -> bool:
        """The average bitrate changed in place from the next frame; False where it cannot be (a stream opened
        without a bitrate, or a rate above the one it was opened with: its VBV would still hold it down)."""
        if self._ctx is None or self.max_bitrate_kbps is None or bitrate_kbps > self.max_bitrate_kbps:
            return False
        if bitrate_kbps != self.bitrate_kbps:
            self._ctx.bit_rate = bitrate_kbps * 1000
            self.bitrate_kbps = bitrate_kbps
        return True

    def encode(self, frame: np.ndarray, keyframe: bool = False) -> tuple[bytes, bool]:
        """A BGR frame -> (all its packets, whether they hold a keyframe); `keyframe`: make it one."""
        if self._ctx is None:
            raise ValueError("this H.264 encoder is closed")
        # OpenCV's BGR -> I420 (BT.601, video range, as swscale's default) takes a third of swscale's time.
        yuv = cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_BGR2YUV_I420)
        picture = self._av.VideoFrame.from_ndarray(yuv, format="yuv420p")
        picture.pts = self.frames
        if keyframe:
            picture.pict_type = self._av.video.frame.PictureType.I
        self.frames += 1
        packets = self._ctx.encode(picture)
        return b"".join(bytes(p) for p in packets), any(p.is_keyframe for p in packets)

    def close(self) -> None:
        ctx, self._ctx = self._ctx, None
        close = getattr(ctx, "close", None)  # PyAV < 14; newer PyAV frees the context with its last reference
        if close is not None:
            close()


def encode_frame(
    encoder: H264Encoder | None,
    frame: np.ndarray,
    timestamp: int,
    options: dict[str, str] | None = None,
    *,
    bitrate_kbps: int | None = None,
    fps: int = 30,
    keyframe: bool = False,
) -> tuple[EncodedFrame | None, H264Encoder]:
    """One frame -> (its access unit with the picture's size, or None while the encoder holds it back; the encoder to
    reuse).

    `encoder` None, one for another frame size, or one that cannot take `bitrate_kbps` in place
    (`H264Encoder.set_bitrate`) gives a new encoder at `bitrate_kbps` and `fps`: its stream starts with a keyframe.
    `keyframe`: this frame is one (in the same stream).
    """
    if not isinstance(frame, np.ndarray) or frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
        raise ValueError("the h264 transport takes BGR uint8 frames of shape (height, width, 3)")
    height, width = frame.shape[:2]
    if encoder is not None and (
        (encoder.width, encoder.height) != (width, height)
        or (bitrate_kbps != encoder.bitrate_kbps and (bitrate_kbps is None or not encoder.set_bitrate(bitrate_kbps)))
    ):
        encoder.close()
        encoder = None
    if encoder is None:
        encoder = H264Encoder(width, height, options, fps, bitrate_kbps)
    data, _ = encoder.encode(frame, keyframe)
    if not data:
        return None, encoder
    return EncodedFrame(H264, timestamp, data, width, height), encoder
