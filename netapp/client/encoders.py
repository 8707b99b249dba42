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
    """One H.264 stream (`netapp.client.h264`). The bitrate changes in place where libx264 allows it (down, and back
    up to the rate the stream opened with); a new frame size, a higher bitrate or a new session starts a new stream
    (SPS, keyframe); a frame the netapp's decoder lost asks for a keyframe in the same stream (the cheap recovery)."""

    codec = H264

    def __init__(self, options: dict[str, str] | None = None) -> None:
        h264.require_av()  # PyAV is an optional extra: say so now rather than on every frame
        self.options = options
        self._lock = threading.Lock()
        self._encoder: h264.H264Encoder | None = None
        self._restart = False  # set from the transport's threads, read by the next `encode`
        self._keyframe = False  # likewise: the next frame is a keyframe of the same stream
        self._stream_start_ts = 0  # timestamp of the frame that started the current stream
        self._last_ts: int | None = None
        self._period_ns: float | None = None  # between the robot's frames, smoothed: the stream's frame rate

    def check(self, frame: Any) -> None:
        if not isinstance(frame, np.ndarray):
            raise TypeError("the h264 transport takes BGR numpy frames")

    def encode(self, timestamp: int, frame: Frame, settings: SendSettings) -> EncodedFrame | None:
        with self._lock:
            restart, self._restart = self._restart, False
            keyframe, self._keyframe = self._keyframe, False
        self._measure_period(timestamp)
        current = self._encoder
        if current is not None and restart:
            self._encoder = None
            current.close()
        fps, bitrate = self.fps, settings.bitrate_kbps
        if settings.fps is not None:  # the adapter's rate: its bitrate is that many frames' bytes a second
            fps = max(1, min(60, round(settings.fps)))
            if bitrate is not None and self._encoder is not None:
                # An open stream spreads its bitrate over the rate it opened at: the same bytes a frame at this one.
                bitrate = max(1, round(bitrate * self._encoder.fps / settings.fps))
        # Looked up on the module at each call, so a test can damage the stream in transit.
        encoded, self._encoder = h264.encode_frame(
            self._encoder,
            frame,  # type: ignore[arg-type]
            timestamp,
            self.options,
            bitrate_kbps=bitrate,
            fps=fps,
            keyframe=keyframe,
        )
        if self._encoder is not current:
            self._stream_start_ts = timestamp
        return encoded

    @property
    def fps(self) -> int:
        """The robot's frame rate as measured (libx264's rate control spreads the bitrate over it, where the settings
        name none); 10 until known."""
        return 10 if self._period_ns is None else max(1, min(60, round(1e9 / self._period_ns)))

    def _measure_period(self, timestamp: int) -> None:
        last, self._last_ts = self._last_ts, timestamp
        if last is None or not 0 < timestamp - last < 2e9:
            return
        period = timestamp - last
        self._period_ns = period if self._period_ns is None else 0.8 * self._period_ns + 0.2 * period

    def restart(self) -> None:
        with self._lock:
            self._restart = True

    def note_error(self, message: dict[str, Any]) -> None:
        if message.get("reason") in H264_KEYFRAME_REASONS and (message.get("timestamp") or 0) >= (
            self._stream_start_ts  # not about a stream already restarted
        ):
            with self._lock:
                self._keyframe = True

    def close(self) -> None:
        encoder, self._encoder = self._encoder, None
        self._last_ts = None  # the next stream measures its own rate (a JPEG spell between is no frame period)
        if encoder is not None:
            encoder.close()


class SwitchingEncoder:
    """JPEG or H.264 frame by frame, as `SendSettings.codec` says (the adapter's choice; None: JPEG), on a transport
    that carries both. The switch falls between frames: H.264 again after JPEG starts a new stream with a keyframe
    (the netapp decodes each codec apart: a Socket.IO event, or the `frames` header's codec, says which)."""

    def __init__(self, jpeg: JpegEncoder, options: dict[str, str] | None = None) -> None:
        self._jpeg = jpeg
        self._h264 = H264StreamEncoder(options)

    def check(self, frame: Any) -> None:
        pass  # a frame H.264 cannot take (bytes) goes as JPEG: `encode`

    def encode(self, timestamp: int, frame: Frame, settings: SendSettings) -> EncodedFrame | None:
        if settings.codec == H264 and isinstance(frame, np.ndarray):
            return self._h264.encode(timestamp, frame, settings)
        self._h264.close()  # the next H.264 frame starts its stream anew
        return self._jpeg.encode(timestamp, frame, settings)

    def restart(self) -> None:
        self._h264.restart()

    def note_error(self, message: dict[str, Any]) -> None:
        self._h264.note_error(message)

    def close(self) -> None:
        self._h264.close()
