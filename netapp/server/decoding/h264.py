"""H.264 frames on the Socket.IO event `image_h264` (5G-ERA wire format), decoded per session with PyAV.

H.264 is a chain of references: a session's packets must go through its decoder one at a time and in arrival order,
or pictures come out corrupt. Socket.IO runs every event as its own task and the pipeline decodes on a thread
pool, so ordering is fixed here, at the moment a message is handed over (synchronously, on the event loop, in
arrival order): the packet is queued on the session's `SerialRunner`, which runs that session's jobs strictly one
after another on a shared decode pool, while different sessions take turns on it. The transport awaits the picture
on the event loop and hands the pipeline the picture itself: no thread (not the inference thread, not a pool shared
by all sessions) ever waits on one session's decoder. Every packet is decoded even if the pipeline later drops its
picture (newest wins), because the decoder needs it as a reference.

Work per stream is bounded before it is spent: the picture size is checked against `--max-pixels` in the event and
in the stream's own SPS (what the decoder would allocate), and a stream whose waiting packets exceed their budget
(count, bytes or age) or whose decoding exceeds its share of CPU time (`Settings.h264_decode_share`: a robot that
floods large keyframes) skips to its next keyframe, its refused packets counted as `h264_overloaded`. A stream
without packets for IDLE_RELEASE_S has its decoder closed, so an idle connection holds no picture buffers.

Each Socket.IO connection gets its own `H264Stream` (see `netapp.server.decoding.decoder.FrameDecoder`), kept by the
Socket.IO transport and closed when the robot disconnects.

A decode failure (or a gap in frame_num: a packet lost after encoding, see h264_bitstream) answers that frame with
a data_error and resets the session's decoder; packets are then refused until the next keyframe (IDR), where the
stream recovers. Other sessions are not affected.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np

from netapp.server.decoding.h264_bitstream import FrameNumTracker, contains_idr, sps_sizes
from netapp.server.decoding.image_limits import check_pixels
from netapp.server.errors import FrameRejected
from netapp.server.settings import Settings

log = logging.getLogger(__name__)

MAX_SIDE = 8192  # width/height beyond this are refused rather than allocated
# A stream the server cannot keep up with skips to its next keyframe (the only place a packet may be left out)
# when its oldest waiting packet has waited this long, or this many packets wait: bounded latency and memory.
MAX_LAG_S = 2.0
MAX_BACKLOG = 300
MAX_BACKLOG_BYTES = 32 * 1024 * 1024  # packets waiting for one stream's decoder
# A stream without packets this long has its decoder closed, freeing its reference pictures (up to 16 of them); it
# resumes at its next keyframe (the toolkit's client sends one at once on the `h264_waiting_keyframe` error).
IDLE_RELEASE_S = 10.0
DECODE_BURST_S = 2.0  # CPU seconds of decoding a stream may spend at once beyond its share (Settings.h264_decode_share)
INSTALL_HINT = "install PyAV on the netapp: pip install 'netapp-toolkit[h264]'"


class SerialRunner:
    """Runs its jobs one at a time, in submission order, on a shared pool.

    One job per pool task (then the runner queues itself again at the back), so sessions with a backlog take
    turns on the pool instead of one of them holding a thread.
    """

    def __init__(self, pool: ThreadPoolExecutor) -> None:
        self._pool = pool
        self._lock = threading.Lock()
        self._jobs: deque[tuple[Callable[[], Any], Future, float, int]] = deque()
        self._active = False
        self._bytes = 0  # held by the jobs waiting

    def backlog(self) -> tuple[int, float, int]:
        """(jobs waiting, seconds the oldest of them has waited, bytes they hold)."""
        with self._lock:
            lag = (time.monotonic() - self._jobs[0][2]) if self._jobs else 0.0
            return len(self._jobs), lag, self._bytes

    def submit(self, fn: Callable[[], Any], size: int = 0) -> Future:
        """Queue `fn`; `size`: the bytes it holds until it runs (for `backlog`)."""
        future: Future = Future()
        with self._lock:
            self._bytes += size
            self._jobs.append((fn, future, time.monotonic(), size))
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
            fn, future, _, size = self._jobs.popleft()
            self._bytes -= size
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
            self._active, self._bytes = False, 0
        for _, future, _, _ in jobs:
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

    @property
    def is_open(self) -> bool:
        """Whether a codec context (and its reference pictures) is held."""
        return self._ctx is not None

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
    pool. `frame()` is called on the event loop in arrival order; `size`, `last_timestamp` and the idle timer live
    there only."""

    def __init__(
        self,
        pool: ThreadPoolExecutor,
        max_pixels: int = Settings.max_pixels,
        decode_share: float = Settings.h264_decode_share,
    ) -> None:
        self.runner = SerialRunner(pool)
        self.decoder = StreamDecoder()
        self.max_pixels = max_pixels
        # Decode budget (CPU seconds): refilled at `decode_share` per second up to DECODE_BURST_S, spent by the
        # decoder thread (`_spent`, only ever added to there; read here).
        self.decode_share = decode_share
        self._credit, self._credited_at, self._spent, self._spent_seen = DECODE_BURST_S, time.monotonic(), 0.0, 0.0
        self.size: tuple[int, int] | None = None
        self.last_timestamp: int | None = None
        self._last_packet = 0.0  # monotonic
        self._idle_timer: asyncio.TimerHandle | None = None

    def frame(self, message: dict[str, Any]) -> asyncio.Future:
        """Queue the packet for decoding before this returns; the transport awaits the returned future for the
        picture (FrameRejected when there is none)."""
        self._last_packet = time.monotonic()
        self._watch_idle()
        data = message["frame"]
        try:
            size = _frame_size(message) or self.size
            if size is None:
                raise FrameRejected(
                    "missing_size",
                    "H.264 frames need integer 'width' and 'height' (at least on "
                    "the first frame) so the netapp can open its decoder",
                )
            # The decoder allocates what the stream's SPS says, whatever the event declares: both are checked.
            check_pixels(*size, self.max_pixels, "an H.264 frame")
            try:
                for width, height in sps_sizes(data):
                    check_pixels(width, height, self.max_pixels, "an H.264 stream (its SPS)")
            except ValueError as exc:
                raise FrameRejected("h264_decode_error", f"{exc}; the decoder waits for the next keyframe") from exc
        except FrameRejected:
            # This packet is not decoded, so the pictures that reference it cannot be: resume at the next keyframe.
            self.reset()
            raise
        self.size = size
        timestamp = message["timestamp"]
        last = self.last_timestamp
        waiting, lag_s, queued_bytes = self.runner.backlog()
        if waiting >= MAX_BACKLOG or lag_s > MAX_LAG_S or queued_bytes + len(data) > MAX_BACKLOG_BYTES:
            future = self.runner.submit(lambda: _skip_to_keyframe(self.decoder, BEHIND))  # the packet is not kept
        elif not self._within_budget():
            future = self.runner.submit(lambda: _skip_to_keyframe(self.decoder, self._over_budget_message()))
        else:
            data = bytes(data)
            future = self.runner.submit(lambda: self._decode(data, size), size=len(data))
        if last is not None and timestamp < last:
            # Refused, but still decoded (above): the frames after it reference this picture.
            future.add_done_callback(lambda f: f.exception())  # its outcome is not needed
            raise FrameRejected(
                "old_timestamp",
                f"timestamp {timestamp} is older than the previous frame's "
                f"{last}: refused (timestamps of one stream must not go back)",
            )
        self.last_timestamp = timestamp
        return asyncio.wrap_future(future)

    def _decode(self, data: bytes, size: tuple[int, int]) -> np.ndarray:
        """On the decode pool: one packet, its CPU time charged to this stream's budget."""
        start = time.thread_time()
        try:
            return self.decoder.decode(data, *size)
        finally:
            self._spent += time.thread_time() - start

    def _within_budget(self) -> bool:
        """Whether this stream may decode another packet now (on the event loop)."""
        now = time.monotonic()
        spent = self._spent
        self._credit = min(DECODE_BURST_S, self._credit + (now - self._credited_at) * self.decode_share)
        self._credit -= spent - self._spent_seen
        self._credited_at, self._spent_seen = now, spent
        return self._credit > 0

    def _over_budget_message(self) -> str:
        return (
            f"H.264: this stream used its decoding budget ({self.decode_share:.2f} CPU seconds per second, bursts "
            f"of {DECODE_BURST_S:.0f} s; its pictures are too large or too many); it skips to the next keyframe"
        )

    # Resetting and closing go through the runner too, behind the packets already queued.
    def reset(self) -> None:
        self._later(self.decoder.reset)

    def close(self) -> None:
        if self._idle_timer is not None:
            self._idle_timer.cancel()
        self._later(self.decoder.close)

    def _later(self, job: Callable[[], None]) -> None:
        future = self.runner.submit(job)
        future.add_done_callback(lambda f: f.exception() and log.warning("H.264 decoder: %s", f.exception()))

    def _watch_idle(self) -> None:
        """Close the decoder of a stream gone quiet for IDLE_RELEASE_S (one timer per stream, re-armed lazily)."""
        if self._idle_timer is not None:
            return
        loop = asyncio.get_running_loop()

        def check() -> None:
            self._idle_timer = None
            idle = time.monotonic() - self._last_packet
            if idle < IDLE_RELEASE_S:
                self._idle_timer = loop.call_later(IDLE_RELEASE_S - idle, check)
            elif self.decoder.is_open:
                self.reset()

        self._idle_timer = loop.call_later(IDLE_RELEASE_S, check)


class H264Decoder:
    """Opens the H.264 streams of the `image_h264` event (see the module docstring), on one shared decode pool."""

    def __init__(
        self, threads: int = 2, max_pixels: int = Settings.max_pixels, decode_share: float = Settings.h264_decode_share
    ) -> None:
        self.max_pixels = max_pixels
        self.decode_share = decode_share
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
        return H264Stream(self._pool, self.max_pixels, self.decode_share)

    def shutdown(self) -> None:
        """Stop taking packets; the queued ones still finish, so nobody waits on them forever."""
        pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=False)


BEHIND = (
    f"H.264: the netapp is behind on this stream (packets wait over {MAX_LAG_S:.0f} s, over {MAX_BACKLOG} of them or "
    f"over {MAX_BACKLOG_BYTES} bytes); it skips to the next keyframe"
)


def _skip_to_keyframe(decoder: StreamDecoder, why: str) -> np.ndarray:
    decoder.reset()
    raise FrameRejected("h264_overloaded", why)


def _frame_size(message: dict[str, Any]) -> tuple[int, int] | None:
    """(width, height) from the message, None if both are absent; FrameRejected if they are unusable."""
    width, height = message.get("width"), message.get("height")
    if width is None and height is None:
        return None
    for name, value in (("width", width), ("height", height)):
        if not isinstance(value, int) or isinstance(value, bool) or not 0 < value <= MAX_SIDE:
            raise FrameRejected("bad_size", f"H.264 frame '{name}' must be an integer in 1..{MAX_SIDE}, got {value!r}")
    return width, height
