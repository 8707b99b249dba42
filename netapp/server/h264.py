"""H.264 frames on the Socket.IO event `image_h264` (5G-ERA wire format), decoded per session with PyAV.

H.264 is a chain of references: a session's packets must go through its decoder one at a time and in arrival order,
or pictures come out corrupt. Socket.IO runs every event as its own task and the pipeline decodes on a thread
pool, so ordering is fixed here, at the moment a message is handed over (synchronously, on the event loop, in
arrival order): the packet is queued on the session's `SerialRunner`, which runs that session's jobs strictly one
after another on a shared decode pool, while different sessions decode in parallel. The callable given to the
pipeline only waits for its packet's picture. Every packet is decoded even if the pipeline later drops its picture
(newest wins), because the decoder needs it as a reference.

Each Socket.IO connection gets its own `H264Stream` (see `netapp.server.frames.FrameDecoder`), kept by the
Socket.IO transport and closed when the robot disconnects.

A decode failure (or a gap in frame_num: a packet lost after encoding, see h264_bitstream) answers that frame with
a data_error and resets the session's decoder; packets are then refused until the next keyframe (IDR), where the
stream recovers. Other sessions are not affected.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from typing import Any

import numpy as np

from netapp.server.errors import FrameRejected
from netapp.server.h264_bitstream import FrameNumTracker, contains_idr

log = logging.getLogger(__name__)

MAX_SIDE = 8192  # width/height beyond this are refused rather than allocated
# A stream the server cannot keep up with skips to its next keyframe (the only place a packet may be left out)
# when its oldest waiting packet has waited this long, or this many packets wait: bounded latency and memory.
MAX_LAG_S = 2.0
MAX_BACKLOG = 300
RESULT_TIMEOUT_S = 30.0  # a safety net: a prepare thread never waits forever on a decode
INSTALL_HINT = "install PyAV on the netapp: pip install 'netapp-toolkit[h264]'"


class SerialRunner:
    """Runs its jobs one at a time, in submission order, on a shared pool.

    One job per pool task (then the runner queues itself again at the back), so sessions with a backlog take
    turns on the pool instead of one of them holding a thread.
    """

    def __init__(self, pool: ThreadPoolExecutor) -> None:
        self._pool = pool
        self._lock = threading.Lock()
        self._jobs: deque[tuple[Callable[[], Any], Future, float]] = deque()
        self._active = False

    def backlog(self) -> tuple[int, float]:
        """(jobs waiting, seconds the oldest of them has waited)."""
        with self._lock:
            return len(self._jobs), (time.monotonic() - self._jobs[0][2]) if self._jobs else 0.0

    def submit(self, fn: Callable[[], Any]) -> Future:
        future: Future = Future()
        with self._lock:
            self._jobs.append((fn, future, time.monotonic()))
            if self._active:
                return future
            self._active = True
        try:
            self._pool.submit(self._run_next)
        except RuntimeError:  # the pool is shut down: nothing will run these jobs
            self._fail_all(RuntimeError("the H.264 decoder is shut down"))
        return future

    def _run_next(self) -> None:
        with self._lock:
            fn, future, _ = self._jobs.popleft()
        try:
            future.set_result(fn())
        except BaseException as exc:  # the job's error belongs to whoever waits for it
            future.set_exception(exc)
        with self._lock:
            if not self._jobs:
                self._active = False
                return
        try:
            self._pool.submit(self._run_next)
        except RuntimeError:
            self._fail_all(RuntimeError("the H.264 decoder is shut down"))

    def _fail_all(self, exc: BaseException) -> None:
        with self._lock:
            jobs, self._jobs = list(self._jobs), deque()
            self._active = False
        for _, future, _ in jobs:
            future.set_exception(exc)


class StreamDecoder:
    """One PyAV H.264 decoder. Not thread-safe: only its session's SerialRunner calls it."""

    def __init__(self) -> None:
        self._ctx: Any = None
        self._size: tuple[int, int] | None = None
        self.waiting_for_keyframe = True  # a decoder can only start at an IDR
        self._frame_nums = FrameNumTracker()
        self.closed = False
        self.resets = 0

    def decode(self, data: bytes, width: int, height: int) -> np.ndarray:
        """One frame's packets -> its BGR picture; FrameRejected (and a reset) if it cannot be decoded."""
        import av

        if self.closed:
            raise FrameRejected("session_closed", "the session was closed")
        if (width, height) != self._size:
            if self._size is not None:
                self.reset()  # the robot restarted its stream at a new size; its new encoder starts with an IDR
            self._size = (width, height)
        if self.waiting_for_keyframe:
            if not contains_idr(data):
                raise FrameRejected(
                    "h264_waiting_keyframe",
                    "H.264: this packet was not decoded because the "
                    "decoder waits for a keyframe (IDR) to start or recover the stream",
                )
            self.waiting_for_keyframe = False
        if not self._frame_nums.follows(data):
            self.reset()  # FFmpeg would conceal the gap and return damaged pictures until the next keyframe
            raise FrameRejected(
                "h264_missing_packet",
                "H.264: a reference picture before this one is missing (a "
                "packet was dropped or lost after encoding); the decoder was reset and waits for the "
                "next keyframe",
            )
        try:
            if self._ctx is None:
                self._ctx = self._open(width, height)
            frames = self._ctx.decode(av.Packet(data))
            corrupt = any(frame.is_corrupt for frame in frames)
        except Exception as exc:  # FFmpeg errors above all, but nothing may leave the decoder half-broken
            self.reset()
            raise FrameRejected(
                "h264_decode_error", f"H.264 decode error: {exc}; the decoder was reset and waits for the next keyframe"
            ) from exc
        if corrupt:
            self.reset()  # pictures that reference a damaged one are damaged too
            raise FrameRejected(
                "h264_decode_error",
                "H.264 decode error: the packet decoded to a corrupt picture "
                "(damaged data); the decoder was reset and waits for the next keyframe",
            )
        if not frames:
            # A zero-latency stream gives one picture per packet; none means damaged data (or an encoder that
            # holds frames back, whose results could not be matched to their frames anyway).
            self.reset()
            raise FrameRejected(
                "h264_no_picture",
                "H.264: no picture came out of this packet (damaged data, or an "
                "encoder that delays frames: use tune=zerolatency, no B-frames); the decoder was "
                "reset and waits for the next keyframe",
            )
        return frames[-1].to_ndarray(format="bgr24")

    @staticmethod
    def _open(width: int, height: int) -> Any:
        import av

        ctx = av.CodecContext.create("h264", "r")
        ctx.width, ctx.height = width, height
        # One thread per decoder: sessions decode in parallel on the pool, and frame threading would delay output.
        ctx.thread_count = 1
        try:
            from av.codec.context import Flags

            ctx.flags |= Flags.low_delay  # output each picture at once even if the stream does not promise it
        except (ImportError, AttributeError, TypeError):  # older PyAV spells flags differently; x264 needs none
            pass
        ctx.open()
        return ctx

    def reset(self) -> None:
        """Forget the stream: a fresh codec context opens at the next keyframe."""
        self._close_ctx()
        self._frame_nums.reset()
        self.waiting_for_keyframe = True
        self.resets += 1

    def close(self) -> None:
        self._close_ctx()
        self.closed = True

    def _close_ctx(self) -> None:
        ctx, self._ctx = self._ctx, None
        close = getattr(ctx, "close", None)  # PyAV < 14; newer PyAV frees the context with its last reference
        if close is not None:
            close()


class H264Stream:
    """A connection's H.264 stream (a `FrameDecoder`): its PyAV decoder, run by its own SerialRunner on the shared
    pool. `frame()` is called on the event loop in arrival order; `size` and `last_timestamp` live there only."""

    def __init__(self, pool: ThreadPoolExecutor) -> None:
        self.runner = SerialRunner(pool)
        self.decoder = StreamDecoder()
        self.size: tuple[int, int] | None = None
        self.last_timestamp: int | None = None

    def frame(self, message: dict[str, Any]) -> Callable[[], np.ndarray]:
        """Queue the packet for decoding before this returns; the callable waits for its picture."""
        try:
            size = _frame_size(message) or self.size
            if size is None:
                raise FrameRejected(
                    "missing_size",
                    "H.264 frames need integer 'width' and 'height' (at least on "
                    "the first frame) so the netapp can open its decoder",
                )
        except FrameRejected:
            # This packet is not decoded, so the pictures that reference it cannot be: resume at the next keyframe.
            self.reset()
            raise
        self.size = size
        timestamp = message["timestamp"]
        last = self.last_timestamp
        if last is not None and timestamp < last:
            # Refused, but still decoded: the frames after it reference this picture.
            self.runner.submit(lambda: self.decoder.decode(bytes(message["frame"]), *size))

            def refuse() -> np.ndarray:
                raise FrameRejected(
                    "old_timestamp",
                    f"timestamp {timestamp} is older than the previous frame's "
                    f"{last}: refused (timestamps of one stream must not go back)",
                )

            return refuse
        self.last_timestamp = timestamp
        waiting, lag_s = self.runner.backlog()
        if waiting >= MAX_BACKLOG or lag_s > MAX_LAG_S:
            future = self.runner.submit(lambda: _skip_to_keyframe(self.decoder))
        else:
            data = bytes(message["frame"])
            future = self.runner.submit(lambda: self.decoder.decode(data, *size))

        def picture() -> np.ndarray:
            try:
                return future.result(timeout=RESULT_TIMEOUT_S)
            except FutureTimeout:
                raise FrameRejected("h264_timeout", f"H.264: no picture within {RESULT_TIMEOUT_S:.0f} s") from None

        return picture

    # Resetting and closing go through the runner too, behind the packets already queued.
    def reset(self) -> None:
        self._later(self.decoder.reset)

    def close(self) -> None:
        self._later(self.decoder.close)

    def _later(self, job: Callable[[], None]) -> None:
        future = self.runner.submit(job)
        future.add_done_callback(lambda f: f.exception() and log.warning("H.264 decoder: %s", f.exception()))


class H264Decoder:
    """Opens the H.264 streams of the `image_h264` event (see the module docstring), on one shared decode pool."""

    def __init__(self, threads: int = 2) -> None:
        try:
            import av  # noqa: F401
        except ImportError:
            self.unavailable: str | None = f"this netapp cannot decode H.264: PyAV is not installed ({INSTALL_HINT})"
            self._pool = None
        else:
            self.unavailable = None
            self._pool = ThreadPoolExecutor(max(1, threads), thread_name_prefix="netapp-h264")

    def open(self) -> H264Stream:
        """A new connection's stream; FrameRejected (the sender hears why) when this netapp cannot decode H.264."""
        if self.unavailable is not None or self._pool is None:
            raise FrameRejected("h264_unavailable", self.unavailable or "the H.264 decoder is shut down")
        return H264Stream(self._pool)

    def shutdown(self) -> None:
        """Stop taking packets; the queued ones still finish, so nobody waits on them forever."""
        pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=False)


def _skip_to_keyframe(decoder: StreamDecoder) -> np.ndarray:
    decoder.reset()
    raise FrameRejected(
        "h264_overloaded",
        "H.264: the netapp is behind on this stream (packets wait over "
        f"{MAX_LAG_S:.0f} s or over {MAX_BACKLOG} of them); it skips to the next keyframe",
    )


def _frame_size(message: dict[str, Any]) -> tuple[int, int] | None:
    """(width, height) from the message, None if both are absent; FrameRejected if they are unusable."""
    width, height = message.get("width"), message.get("height")
    if width is None and height is None:
        return None
    for name, value in (("width", width), ("height", height)):
        if not isinstance(value, int) or isinstance(value, bool) or not 0 < value <= MAX_SIDE:
            raise FrameRejected("bad_size", f"H.264 frame '{name}' must be an integer in 1..{MAX_SIDE}, got {value!r}")
    return width, height
