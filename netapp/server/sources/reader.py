"""One camera's reading thread: connect with PyAV (FFmpeg), decode every picture, hand on the newest, reconnect.

H.264 pictures reference earlier ones, so every picture is decoded, here, on this thread; each decoded picture goes
to `offer`, which keeps only the newest for the model (`netapp.server.sources.hub`). Converting a picture to BGR is
left to the pipeline, for the one picture the model takes. Everything is bounded: FFmpeg's connect and read time
(PyAV's interrupt callback, and the socket's own timeout), the picture's size (the stream's, before its first picture
is decoded, and each picture's: FFmpeg's probe and decoder are given the bound, so nothing is decoded at a size over
it), a packet's bytes. A damaged picture, and those after it until the next keyframe, are never handed on. When
decoding falls behind the camera (`keeping_up`), only keyframes are decoded from then on for this connection (one log
line, a metric); a camera that pauses (no packet for PAUSE_S) is not that, and one that hangs (no packet for
READ_TIMEOUT_S) is lost then, with the reason in words.

The thread ends within about READ_TIMEOUT_S of `stop()`: FFmpeg cannot be interrupted from another thread, so it is
told at the next packet, or when its read times out. It holds no socket after it ends (the container is closed).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from netapp.backoff import Outage, backoff_s
from netapp.server.decoding.image_limits import check_pixels
from netapp.server.errors import FrameRejected
from netapp.server.settings import SourceSpec
from netapp.server.sources.keeping_up import KeepingUp
from netapp.server.sources.metrics import SourceMetrics
from netapp.server.sources.naming import open_options
from netapp.server.sources.redaction import redact_camera

log = logging.getLogger(__name__)

OPEN_TIMEOUT_S = 5.0  # connecting and reading the stream's description
READ_TIMEOUT_S = 2.0  # no packet this long: the camera is gone
# No packet this long: the camera paused (a hiccup, or it hangs), which is no decoding backlog: the pictures after it
# are judged afresh (a decoder behind the camera reads the packets waiting for it at once)
PAUSE_S = 1.0
# offer(picture, packet bytes): a decoded av.VideoFrame, on this thread
Offer = Callable[[Any, int], None]


class StreamEnded(Exception):
    """The camera closed its stream (or sent nothing usable)."""


STALLED = f"no data for {READ_TIMEOUT_S:g} s: the camera hangs, or the network to it is cut"


class CameraReader:
    def __init__(
        self, spec: SourceSpec, offer: Offer, metrics: SourceMetrics, max_pixels: int, max_packet_bytes: int
    ) -> None:
        self.spec = spec
        self.offer = offer
        self.max_pixels = max_pixels
        self.max_packet_bytes = max_packet_bytes
        self.outage = Outage(spec.name)
        self.keyframes_only = False
        self.last_packet_at: float | None = None  # monotonic; None until a stream is open
        self._metrics = metrics
        self._up = metrics.up.labels(source=spec.name)
        self._decoded = metrics.decoded.labels(source=spec.name)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"netapp-camera-{spec.name}", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        """Ask the thread to end (see the module for how soon)."""
        self._stop.set()

    def join(self, timeout_s: float = OPEN_TIMEOUT_S + READ_TIMEOUT_S) -> bool:
        """Wait for the thread; whether it ended (a thread never started has)."""
        if self._thread.ident is None:
            return True
        self._thread.join(timeout_s)
        return not self._thread.is_alive()

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    # -- the thread -------------------------------------------------------------------------------------------------

    def _run(self) -> None:
        refused = ""  # the last bound the camera's stream broke, told: a camera that answers, refused, is told so
        while not self._stop.is_set():
            bound = False  # the stream broke a bound (its size): the camera answers, and is refused
            try:
                self._read()
                why = "the camera ended its stream"
            except Exception as exc:  # FFmpeg's errors above all; nothing may end the thread but stop()
                why = STALLED if self._stalled() else describe(exc, self.spec)
                bound = isinstance(exc, FrameRejected)
            self._up.set(0)
            if self._stop.is_set():
                break
            outages = self.outage.outages
            line = self.outage.failed(time.monotonic(), why)
            if self.outage.outages > outages:
                self._metrics.outages.labels(source=self.spec.name).inc()
            if line:
                log.warning("%s", line)
            elif bound and why != refused:  # during an outage told for another reason
                log.warning("camera %s: refused (%s)", self.spec.name, why)
            refused = why if bound else refused
            self._stop.wait(backoff_s(self.outage.attempts - 1))

    def _stalled(self) -> bool:
        """Whether the stream broke after READ_TIMEOUT_S without a packet (FFmpeg then says only "Immediate exit
        requested", its read interrupted, or chokes on the half packet it had)."""
        last = self.last_packet_at
        return last is not None and time.monotonic() - last >= READ_TIMEOUT_S - 0.1

    def _read(self) -> None:
        import av

        spec = self.spec
        options = open_options(spec, av.library_versions["libavformat"][0], self.max_pixels)
        container = av.open(spec.url, options=options, timeout=(OPEN_TIMEOUT_S, READ_TIMEOUT_S))
        try:
            if not container.streams.video:
                raise StreamEnded("the camera's stream has no video")
            stream = container.streams.video[0]
            ctx = stream.codec_context
            if ctx.width and ctx.height:  # what the SDP or SPS says (the probe decoded nothing over the bound)
                check_pixels(ctx.width, ctx.height, self.max_pixels, f"camera {spec.name}'s stream")
            # the decoder's own bound: a later SPS claiming more is refused by FFmpeg before a picture is allocated
            ctx.options = {**ctx.options, "max_pixels": str(self.max_pixels)}
            # FFmpeg's own threads stay at its default (slice threads, no frame delay): with one thread, this FFmpeg
            # flags every keyframe of x264's zero-latency streams corrupt (measured with tests/support/rtsp_camera.py).
            self.keyframes_only = False  # a new connection tries every picture again
            self._metrics.keyframes_only.labels(source=spec.name).set(0)
            self._decode(container, stream)
        finally:
            container.close()

    def _decode(self, container: Any, stream: Any) -> None:
        spec = self.spec
        keeping_up = KeepingUp()
        damaged = False  # a damaged picture was seen: wait for a keyframe
        self.last_packet_at = waiting_since = time.monotonic()
        for packet in container.demux(stream):
            if self._stop.is_set():
                return
            arrived = time.monotonic()
            if arrived - waiting_since >= READ_TIMEOUT_S - 0.1:
                raise StreamEnded(STALLED)  # the read timed out: what FFmpeg hands on now is what it had
            if arrived - waiting_since >= PAUSE_S:
                keeping_up.restart()
            self.last_packet_at = arrived
            if packet.size > self.max_packet_bytes:
                self._metrics.skipped.labels(source=spec.name, reason="packet_too_large").inc()
                damaged = True  # the pictures after it reference it
                continue
            for picture in packet.decode():
                self._decoded.inc()
                check_pixels(picture.width, picture.height, self.max_pixels, f"camera {spec.name}'s picture")
                if picture.is_corrupt or (damaged and not picture.key_frame):
                    damaged = True
                    self._metrics.skipped.labels(source=spec.name, reason="corrupt").inc()
                    continue
                damaged = False
                line = self.outage.connected(time.monotonic())
                if line:
                    log.info("%s (%dx%d)", line, picture.width, picture.height)
                    self._up.set(1)
                if not self.keyframes_only and keeping_up.cannot_keep_up(time.monotonic(), picture.time):
                    self._keyframes_only(stream)
                self.offer(picture, packet.size)
            waiting_since = time.monotonic()  # decoding done: from here on, the wait is the camera's
        raise StreamEnded("the camera ended its stream")

    def _keyframes_only(self, stream: Any) -> None:
        self.keyframes_only = True
        stream.codec_context.skip_frame = "NONKEY"
        self._metrics.keyframes_only.labels(source=self.spec.name).set(1)
        log.warning(
            "camera %s: decoding cannot keep up with the camera: only its keyframes are decoded from now on (lower "
            "its frame rate or size, or give the netapp more CPU)",
            self.spec.name,
        )


def describe(exc: BaseException, spec: SourceSpec) -> str:
    """One line for a log: FFmpeg's message in words (not its error number, nor the URL it opened), or the bound a
    picture broke; redacted all the same (an exception of another kind may carry the URL)."""
    if isinstance(exc, FrameRejected):
        return str(exc)
    strerror = getattr(exc, "strerror", None)  # an FFmpegError's words
    text = (strerror if isinstance(strerror, str) and strerror else str(exc)).strip() or type(exc).__name__
    text = redact_camera(text, spec.url)
    return text.splitlines()[0][:200]
