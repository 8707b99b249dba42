"""Frame encoders: a robot's frame -> the one frame type, `netapp.frame.EncodedFrame` (a JPEG per frame, or an H.264
access unit of a stream).

An encoder is apart from the transport that carries its frames: "http" and "ws" send JPEGs, "h264" sends an
H.264 stream over the same Socket.IO transport as "ws"; "frames" carries either, "rtp" H.264. Each transport turns
the frame into its own wire at its edge only. The client calls `encode` for one frame at a time, in the order the
frames go on the wire.
"""

from __future__ import annotations

import threading
from typing import Any, Protocol

import cv2
import numpy as np

import netapp.client.h264 as h264
from netapp.client.send_settings import SendSettings
from netapp.frame import H264, JPEG, EncodedFrame
from netapp.protocol import H264_KEYFRAME_REASONS

Frame = np.ndarray | bytes


class FrameEncoder(Protocol):
    """Turns frames into `EncodedFrame`s; may keep state across frames (a video stream)."""

    def check(self, frame: Any) -> None:
        """Raise TypeError for a frame this encoder cannot take (at `send()`, before the frame is queued)."""

    def encode(self, timestamp: int, frame: Frame, settings: SendSettings) -> EncodedFrame | None:
        """The frame ready for the wire with the `settings` in force, or None while the encoder holds it back (no
        bytes for it yet)."""

    def restart(self) -> None:
        """The next frame starts a new stream: a new session or netapp decodes from scratch."""

    def note_error(self, message: dict[str, Any]) -> None:
        """A `data_error` from the netapp, before its frame's slot is freed (so the next frame can react to it)."""

    def close(self) -> None:
        """Free what the encoder holds."""


class JpegEncoder:
    """Each frame on its own as a JPEG at `SendSettings.jpeg_quality`; JPEG bytes pass through untouched."""

    codec = JPEG

    def check(self, frame: Any) -> None:
        pass  # anything cv2 cannot encode fails at `encode` and is counted as an error, as for a bad array

    def encode(self, timestamp: int, frame: Frame, settings: SendSettings) -> EncodedFrame:
        if isinstance(frame, (bytes, bytearray)):
            data = bytes(frame)
        else:
            ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, settings.jpeg_quality])
            if not ok:
                raise ValueError("could not encode the frame as JPEG")
            data = buf.tobytes()
        return EncodedFrame(JPEG, timestamp, data)

    def restart(self) -> None:
        pass

    def note_error(self, message: dict[str, Any]) -> None:
        pass

    def close(self) -> None:
        pass


class H264StreamEncoder:
    """One H.264 stream (`netapp.client.h264`), restarted with a keyframe when the netapp's decoder lost it, and
    where the frame size or the bitrate changes (a new SPS and keyframe, never a mid-stream switch)."""

    codec = H264

    def __init__(self, options: dict[str, str] | None = None) -> None:
        h264.require_av()  # PyAV is an optional extra: say so now rather than on every frame
        self.options = options
        self._lock = threading.Lock()
        self._encoder: h264.H264Encoder | None = None
        self._restart = False  # set from the transport's threads, read by the next `encode`
        self._stream_start_ts = 0  # timestamp of the frame that started the current stream
        self._bitrate_kbps: int | None = None  # the current stream's (SendSettings.bitrate_kbps)

    def check(self, frame: Any) -> None:
        if not isinstance(frame, np.ndarray):
            raise TypeError("the h264 transport takes BGR numpy frames")

    def encode(self, timestamp: int, frame: Frame, settings: SendSettings) -> EncodedFrame | None:
        with self._lock:
            restart, self._restart = self._restart, False
        current = self._encoder
        # A new size or bitrate starts a new stream (SPS, keyframe), never a switch in the middle of one.
        if current is not None and (
            restart or self._bitrate_kbps != settings.bitrate_kbps or not current.takes(frame)  # type: ignore[arg-type]
        ):
            self._encoder = None
            current.close()
        if self._encoder is None:
            self._stream_start_ts = timestamp
            self._bitrate_kbps = settings.bitrate_kbps
        options = self.options
        if settings.bitrate_kbps is not None:  # libx264's average bitrate instead of its constant quality
            options = {**(options or {}), "b": f"{settings.bitrate_kbps}k"}
        # Looked up on the module at each call, so a test can damage the stream in transit.
        encoded, self._encoder = h264.encode_frame(self._encoder, frame, timestamp, options)
        return encoded

    def restart(self) -> None:
        with self._lock:
            self._restart = True

    def note_error(self, message: dict[str, Any]) -> None:
        if message.get("reason") in H264_KEYFRAME_REASONS and (message.get("timestamp") or 0) >= (
            self._stream_start_ts  # not about a stream already restarted
        ):
            self.restart()

    def close(self) -> None:
        encoder, self._encoder = self._encoder, None
        if encoder is not None:
            encoder.close()
