"""H.264 frames (Socket.IO's `image_h264` event, the frames wire's H.264 codec, RTP's access units), decoded per
session with PyAV.

H.264 is a chain of references: a session's packets must go through its decoder one at a time and in arrival order,
or pictures come out corrupt. Ordering is fixed at the moment a message is handed over (synchronously, on the event
loop, in arrival order): the packet is queued on its stream (`H264Stream`), and its frame carries the decoding
through to it. That decoding runs on the inference lane that runs the frame (no hop to a decode pool and back): it
decodes every packet queued before its own first, in order, so a frame the pipeline dropped (newest wins, a missed
deadline) still has its packet decoded, as the decoder needs it as a reference; only its picture is not converted.
A robot has one frame in process at a time, so a stream's packets are never decoded on two lanes at once, and the
decoding is charged to the robot's turn like a JPEG's (`Session.cost_s`, the scheduler's weighed turns).

Work per stream is bounded before it is spent: the picture size is checked against `--max-pixels` in the event and
in the stream's own SPS (what the decoder would allocate), and a stream whose waiting packets exceed their budget
(count, bytes or age) or whose decoding exceeds its share of CPU time (`Settings.h264_decode_share`: a robot that
floods large keyframes) skips to its next keyframe, its waiting packets dropped and its refused ones counted as
`h264_overloaded`. A stream without packets for IDLE_RELEASE_S has its decoder closed, so an idle connection holds no
picture buffers.

Each connection gets its own `H264Stream` (see `netapp.server.decoding.decoder.FrameDecoder`), kept by its
`Connection` (`netapp.server.connection`) and closed with it.

A decode failure (or a gap in frame_num: a packet lost after encoding, see h264_bitstream) answers that frame with
a data_error and resets the session's decoder; packets are then refused until the next keyframe (IDR), where the
stream recovers. Other sessions are not affected.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NoReturn

import cv2
import numpy as np

from netapp.frame import EncodedFrame
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
# A stream's waiting packets are decoded on one lane in one turn: at most about this much decoding (estimated from
# what the stream's packets cost so far), so a flood cannot hold a lane for long while other robots wait.
MAX_PENDING_DECODE_S = 0.25
# A stream without packets this long has its decoder closed, freeing its reference pictures (up to 16 of them); it
# resumes at its next keyframe (the toolkit's client sends one at once on the `h264_waiting_keyframe` error).
IDLE_RELEASE_S = 10.0
DECODE_BURST_S = 2.0  # CPU seconds of decoding a stream may spend at once beyond its share (Settings.h264_decode_share)
INSTALL_HINT = "install PyAV on the netapp: pip install 'netapp-toolkit[h264]'"


class StreamDecoder:
    """One PyAV H.264 decoder. Not thread-safe: only its session's SerialRunner calls it."""

    def __init__(self) -> None:
        self._ctx: Any = None
        self._size: tuple[int, int] | None = None
        self.waiting_for_keyframe = True  # a decoder can only start at an IDR
        self._frame_nums = FrameNumTracker()
        self.closed = False
        self.resets = 0

    def decode(self, data: bytes, width: int, height: int, picture: bool = True) -> np.ndarray | None:
        """One frame's packets -> its BGR picture (None without `picture`: a reference only, not converted);
        FrameRejected (and a reset) if it cannot be decoded."""
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
        return to_bgr(frames[-1]) if picture else None

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


def to_bgr(frame: Any) -> np.ndarray:
    """A decoded picture as BGR: OpenCV's I420 -> BGR (BT.601, video range, as swscale's default) takes a quarter
    of swscale's time; any other layout (full range, 4:2:2, odd sizes) goes through swscale."""
    if frame.format.name == "yuv420p" and frame.width % 2 == 0 and frame.height % 2 == 0:
        return cv2.cvtColor(frame.to_ndarray(), cv2.COLOR_YUV2BGR_I420)
    return frame.to_ndarray(format="bgr24")


class H264Stream:
    """A connection's H.264 stream (a `FrameDecoder`): its packets wait here in arrival order and are decoded on the
    inference lane that runs their frame (`in_order`: never on the prepare pool). `frame()` is called on the event
    loop in arrival order; `size`, `last_timestamp` and the idle timer live there only."""

    in_order = True  # each frame's decoding needs the packets before it decoded first: run it on its lane

    def __init__(self, max_pixels: int = Settings.max_pixels, decode_share: float = Settings.h264_decode_share) -> None:
        self.decoder = StreamDecoder()
        self.max_pixels = max_pixels
        # Decode budget (CPU seconds): refilled at `decode_share` per second up to DECODE_BURST_S, spent on the
        # lanes (`_spent`, only ever added to there; read on the loop).
        self.decode_share = decode_share
        self._credit, self._credited_at, self._spent, self._spent_seen = DECODE_BURST_S, time.monotonic(), 0.0, 0.0
        self._decoded_bytes = 0  # what `_spent` decoded (a lane adds to both): a waiting byte's estimated cost
        self.size: tuple[int, int] | None = None
        self.last_timestamp: int | None = None
        self._last_packet = 0.0  # monotonic
        self._idle_timer: asyncio.TimerHandle | None = None
        self._jobs = _Jobs()
        self._decoding = threading.Lock()  # held while the decoder runs (a lane, or the loop releasing it idle)

    def frame(self, frame: EncodedFrame) -> Callable[[], np.ndarray]:
        """Queue the frame's access unit before this returns, and return its decoding (FrameRejected when it cannot
        be queued, or, from the decoding, when it gives no picture)."""
        self._last_packet = time.monotonic()
        self._watch_idle()
        data = frame.payload
        try:
            size = _frame_size(frame) or self.size
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
        timestamp = frame.timestamp
        last = self.last_timestamp
        waiting, lag_s, queued_bytes = self.backlog()
        pending_s = (queued_bytes + len(data)) * self._spent / self._decoded_bytes if self._decoded_bytes else 0.0
        if (
            waiting >= MAX_BACKLOG
            or lag_s > MAX_LAG_S
            or queued_bytes + len(data) > MAX_BACKLOG_BYTES
            or pending_s > MAX_PENDING_DECODE_S
        ):
            self._skip_to_keyframe(BEHIND)  # the packet is not kept
        if not self._within_budget(pending_s):
            self._skip_to_keyframe(self._over_budget_message())
        ticket = self._jobs.add(bytes(data), size)
        if last is not None and timestamp < last:
            # Refused, but still decoded (queued above, decoded before the next frame's packet): the frames after
            # it reference this picture.
            raise FrameRejected(
                "old_timestamp",
                f"timestamp {timestamp} is older than the previous frame's "
                f"{last}: refused (timestamps of one stream must not go back)",
            )
        self.last_timestamp = timestamp
        return functools.partial(self._decode_through, ticket)

    def backlog(self) -> tuple[int, float, int]:
        """(packets waiting for their decoding, seconds the oldest has waited, bytes they hold)."""
        return self._jobs.backlog()

    def _decode_through(self, ticket: int) -> np.ndarray:
        """On the lane that runs this packet's frame: decode every packet queued before it (superseded frames'
        pictures, needed as references, thrown away), run the resets between them, then this one's picture.

        A robot has one frame in process at a time, so the lock is never waited on for long: only the loop's idle
        release, which never waits, takes it otherwise."""
        with self._decoding:
            while True:
                job = self._jobs.take(ticket)
                if job is None:  # skipped to a keyframe (or released idle) after it was queued
                    raise FrameRejected("h264_overloaded", SKIPPED)
                if job.data is None:
                    job.run(self.decoder)
                elif job.ticket == ticket:
                    picture = self._decode(job.data, job.size)
                    assert picture is not None
                    return picture
                else:
                    with contextlib.suppress(FrameRejected):  # its frame was answered already; a reset is done
                        self._decode(job.data, job.size, picture=False)

    def _decode(self, data: bytes, size: tuple[int, int], picture: bool = True) -> np.ndarray | None:
        """One packet, its CPU time charged to this stream's budget."""
        start = time.thread_time()
        try:
            return self.decoder.decode(data, *size, picture)
        finally:
            self._spent += time.thread_time() - start
            self._decoded_bytes += len(data)

    def _skip_to_keyframe(self, why: str) -> NoReturn:
        """Refuse this packet and drop the ones waiting (their frames, if still queued, hear `SKIPPED`): the stream
        resumes at its next keyframe."""
        self._jobs.clear()
        self.reset()
        raise FrameRejected("h264_overloaded", why)

    def _within_budget(self, pending_s: float) -> bool:
        """Whether this stream may decode another packet now, `pending_s` of decoding waiting already (on the event
        loop)."""
        now = time.monotonic()
        spent = self._spent
        self._credit = min(DECODE_BURST_S, self._credit + (now - self._credited_at) * self.decode_share)
        self._credit -= spent - self._spent_seen
        self._credited_at, self._spent_seen = now, spent
        return self._credit - pending_s > 0

    def _over_budget_message(self) -> str:
        return (
            f"H.264: this stream used its decoding budget ({self.decode_share:.2f} CPU seconds per second, bursts "
            f"of {DECODE_BURST_S:.0f} s; its pictures are too large or too many); it skips to the next keyframe"
        )

    # Resetting and closing wait in line behind the packets already queued.
    def reset(self) -> None:
        self._jobs.add(None, None, StreamDecoder.reset)

    def close(self) -> None:
        """The connection went away: drop what waits and free the decoder now, or (a lane is decoding) after it,
        or with the stream's last reference (the lane's frame is answered SessionClosed)."""
        if self._idle_timer is not None:
            self._idle_timer.cancel()
        self._jobs.clear()
        if not self._release_if_free(StreamDecoder.close):
            self._jobs.add(None, None, StreamDecoder.close)

    def _release_if_free(self, step: Callable[[StreamDecoder], None]) -> bool:
        """On the loop, never waiting: unless a lane is decoding (then False), drop what waits (the frames still
        queued hear SKIPPED) and run `step` (a reset or a close) on the decoder."""
        if not self._decoding.acquire(blocking=False):
            return False
        try:
            self._jobs.drain()
            step(self.decoder)
        finally:
            self._decoding.release()
        return True

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
            elif (self.decoder.is_open or self.backlog()[0]) and not self._release_if_free(StreamDecoder.reset):
                self._idle_timer = loop.call_later(IDLE_RELEASE_S, check)  # a lane is decoding: look again later

        self._idle_timer = loop.call_later(IDLE_RELEASE_S, check)


@dataclass
class _Job:
    """A packet to decode (`data`), or a step for the decoder between packets (`step`: reset, close)."""

    ticket: int
    data: bytes | None
    size: tuple[int, int] | None
    step: Callable[[StreamDecoder], None] | None
    queued_at: float = field(default_factory=time.monotonic)

    def run(self, decoder: StreamDecoder) -> None:
        assert self.step is not None
        self.step(decoder)


class _Jobs:
    """A stream's waiting packets and steps, in arrival order: added on the loop, taken on a lane."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._jobs: deque[_Job] = deque()
        self._next = 0
        self._packets = 0  # jobs that are packets (`data`), and the bytes they hold: read per frame, kept as counts
        self._bytes = 0

    def add(
        self, data: bytes | None, size: tuple[int, int] | None, step: Callable[[StreamDecoder], None] | None = None
    ) -> int:
        with self._lock:
            last = self._jobs[-1] if self._jobs else None
            if data is None and last is not None and last.data is None and last.step is step:
                return last.ticket  # the same step again adds nothing: refused packets in a row leave one reset
            self._next += 1
            self._jobs.append(_Job(self._next, data, size, step))
            if data is not None:
                self._packets += 1
                self._bytes += len(data)
            return self._next

    def take(self, through: int) -> _Job | None:
        """The oldest job if it is at or before ticket `through`; None when that ticket is gone."""
        with self._lock:
            if not self._jobs or self._jobs[0].ticket > through:
                return None
            job = self._jobs.popleft()
            if job.data is not None:
                self._packets -= 1
                self._bytes -= len(job.data)
            return job

    def drain(self) -> None:
        """Drop every job, steps too (the caller resets or closes the decoder itself)."""
        with self._lock:
            self._jobs, self._packets, self._bytes = deque(), 0, 0

    def clear(self) -> None:
        """Drop the waiting packets (the steps stay, in order)."""
        with self._lock:
            self._jobs = deque(job for job in self._jobs if job.data is None)
            self._packets = self._bytes = 0

    def backlog(self) -> tuple[int, float, int]:
        """(packets waiting, seconds the oldest packet has waited, bytes they hold). A step is no work waiting: a
        reset left by refused packets, with no packet since, must not make the stream look behind (that refused its
        every packet after MAX_LAG_S, keyframes too, for good)."""
        with self._lock:
            oldest = next((job.queued_at for job in self._jobs if job.data is not None), None)  # after a step or two
            lag = 0.0 if oldest is None else time.monotonic() - oldest
            return self._packets, lag, self._bytes


class H264Decoder:
    """Opens the H.264 streams of the `image_h264` event (see the module docstring)."""

    def __init__(self, max_pixels: int = Settings.max_pixels, decode_share: float = Settings.h264_decode_share) -> None:
        self.max_pixels = max_pixels
        self.decode_share = decode_share
        try:
            import av  # noqa: F401
        except ImportError:
            self.unavailable: str | None = f"this netapp cannot decode H.264: PyAV is not installed ({INSTALL_HINT})"
        else:
            self.unavailable = None

    def open(self) -> H264Stream:
        """A new connection's stream; FrameRejected (the sender hears why) when this netapp cannot decode H.264."""
        if self.unavailable is not None:
            raise FrameRejected("h264_unavailable", self.unavailable)
        return H264Stream(self.max_pixels, self.decode_share)


SKIPPED = "H.264: the netapp skipped this packet to catch up (or it waited too long); it resumes at the next keyframe"
BEHIND = (
    f"H.264: the netapp is behind on this stream (packets wait over {MAX_LAG_S:.0f} s, over {MAX_BACKLOG} of them, "
    f"over {MAX_BACKLOG_BYTES} bytes or over {MAX_PENDING_DECODE_S} s of decoding); it skips to the next keyframe"
)


def _frame_size(frame: EncodedFrame) -> tuple[int, int] | None:
    """(width, height) of the frame, None where both are 0 (as before); FrameRejected if they are unusable."""
    width, height = frame.width, frame.height
    if not width and not height:
        return None
    for name, value in (("width", width), ("height", height)):
        if not isinstance(value, int) or isinstance(value, bool) or not 0 < value <= MAX_SIDE:
            raise FrameRejected("bad_size", f"H.264 frame '{name}' must be an integer in 1..{MAX_SIDE}, got {value!r}")
    return width, height
