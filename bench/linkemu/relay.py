"""Asyncio TCP relay that delays each chunk while keeping byte order.

Each direction of each connection is a :class:`_Pipe`: a reader task stamps every chunk with
a release time (``arrival + delay +/- jitter``, never before the previous chunk's: TCP is
ordered) and a writer task writes it out at that time. A bounded queue gives backpressure to
the sender, like a bottleneck buffer. Optionally the pipe also shapes rate (a link-wide
serialisation clock per direction) and models loss as retransmission delay, for hosts where the
kernel path (netns + tbf + nftables) is unavailable.
"""

from __future__ import annotations

import asyncio
import logging
import math
import random
from collections import deque
from dataclasses import dataclass

log = logging.getLogger("linkemu")

MSS = 1448  # payload of one TCP segment with timestamps on a 1500-byte MTU
RTO_MIN_S = 0.2  # Linux TCP_RTO_MIN
_EOF = b""
_HALF_TICK_S = 0.0005


@dataclass
class RateClock:
    """Serialisation clock of one link direction, shared by all connections on that link."""

    rate_bps: float
    free_at: float = 0.0

    def transmit(self, now: float, nbytes: int) -> float:
        """Return when the last byte of ``nbytes`` queued at ``now`` has left the link."""
        self.free_at = max(self.free_at, now) + nbytes * 8 / self.rate_bps
        return self.free_at


@dataclass
class DirectionModel:
    """Impairments applied by the relay to one direction of the link."""

    delay_s: float
    jitter_s: float = 0.0
    rate: RateClock | None = None
    loss: float = 0.0  # probability per MSS-sized segment, userspace model only
    rng: random.Random | None = None
    nominal_bps: float | None = None  # link rate for queue sizing when the kernel shapes it
    segments: int = 0  # MSS-sized segments seen, for loss statistics
    lost: int = 0  # chunks that paid a retransmission delay
    # While the link is down (a schedule's outage, modelled here when the kernel does not drop): nothing leaves
    # before this loop time. A chunk sent during an outage arrives ``delay`` after it ends.
    down_until: float = 0.0

    def __post_init__(self) -> None:
        if self.rng is None:
            self.rng = random.Random()

    def release_time(self, now: float, nbytes: int) -> float:
        """Release time of a chunk that arrived at ``now`` (before order is enforced)."""
        assert self.rng is not None
        now = max(now, self.down_until)
        t = self.rate.transmit(now, nbytes) if self.rate is not None else now
        d = self.delay_s
        if self.jitter_s:
            d = max(0.0, d + self.rng.uniform(-self.jitter_s, self.jitter_s))
        t += d
        if self.loss and nbytes:
            segments = math.ceil(nbytes / MSS)
            self.segments += segments
            if self.rng.random() < 1 - (1 - self.loss) ** segments:
                self.lost += 1
                # A lost segment costs one RTT when enough segments follow it for three
                # duplicate ACKs (fast retransmit), else a retransmission timeout.
                rtt = 2 * self.delay_s
                t += rtt if segments >= 4 else max(RTO_MIN_S, rtt) + rtt
        return t

    def queue_limit(self) -> int:
        """Bytes a pipe may hold: a few bandwidth-delay products, so the queue never caps
        throughput, but bounded so a fast sender feels backpressure."""
        rate_bps = self.rate.rate_bps if self.rate is not None else self.nominal_bps
        if rate_bps is None:
            return 8 << 20
        bdp = rate_bps / 8 * (self.delay_s + self.jitter_s)
        return max(256 << 10, int(4 * bdp))


class _Pipe:
    """One direction of one relayed connection."""

    def __init__(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        model: DirectionModel,
        not_before: float = 0.0,
        chunk: int = 64 << 10,
    ) -> None:
        self._reader = reader
        self._writer = writer
        self._model = model
        self._last = not_before
        self._chunk = chunk
        self._queue: deque[tuple[float, bytes]] = deque()
        self._queued = 0
        self._has_item = asyncio.Event()
        self._has_space = asyncio.Event()
        self._has_space.set()

    async def run(self) -> None:
        """Relay until EOF (propagated as a half-close) or a connection error (raised)."""
        tasks = {asyncio.create_task(self._feed()), asyncio.create_task(self._deliver())}
        try:
            # Returns when both finish, or as soon as either fails.
            done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_EXCEPTION)
            for t in done:
                if t.exception() is not None:
                    raise t.exception()  # type: ignore[misc]
        finally:
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

    async def _feed(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            while self._queued >= self._model.queue_limit():  # the rate may change mid-run (a schedule)
                self._has_space.clear()
                await self._has_space.wait()
            # Small reads where the relay shapes the rate, so a chunk does not leave at once (the rate may be set
            # mid-run by a schedule).
            data = await self._reader.read(self._chunk if self._model.rate is None else min(self._chunk, 16 << 10))
            now = loop.time()
            release = max(self._model.release_time(now, len(data)) if data else now + self._model.delay_s, self._last)
            self._last = release
            self._queue.append((release, data))
            self._queued += len(data)
            self._has_item.set()
            if not data:
                return

    async def _deliver(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            while not self._queue:
                self._has_item.clear()
                await self._has_item.wait()
            release, data = self._queue.popleft()
            # epoll timeouts have 1 ms granularity and asyncio rounds them up, so a plain
            # sleep(wait) is late by 0..1 ms. Sleeping half a millisecond less rounds to the
            # nearest millisecond instead: unbiased, at most 0.5 ms early or late.
            wait = release - loop.time()
            if wait > _HALF_TICK_S:
                await asyncio.sleep(wait - _HALF_TICK_S)
            while (down := self._model.down_until - loop.time()) > _HALF_TICK_S:
                await asyncio.sleep(down)  # in flight when the link went down: held until it is back
            if not data:
                if self._writer.can_write_eof() and not self._writer.is_closing():
                    self._writer.write_eof()
                return
            self._writer.write(data)
            await self._writer.drain()
            self._queued -= len(data)
            self._has_space.set()


async def relay_connection(
    client: tuple[asyncio.StreamReader, asyncio.StreamWriter],
    upstream: tuple[asyncio.StreamReader, asyncio.StreamWriter],
    up: DirectionModel,
    down: DirectionModel,
    up_not_before: float = 0.0,
) -> None:
    """Relay both directions until both are closed; a reset on either side aborts both."""
    c_reader, c_writer = client
    u_reader, u_writer = upstream
    pipes = [_Pipe(c_reader, u_writer, up, not_before=up_not_before), _Pipe(u_reader, c_writer, down)]
    tasks = [asyncio.create_task(p.run()) for p in pipes]
    clean = False
    try:
        failed = False
        for fut in asyncio.as_completed(tasks):
            try:
                await fut
            except (ConnectionError, OSError):
                # Either peer went away mid-stream: tear down the other side at once, as a
                # lost connection would, instead of waiting for it to notice on its own.
                failed = True
                for w in (c_writer, u_writer):
                    w.transport.abort()
        clean = not failed
    finally:
        for t in tasks:
            t.cancel()
        try:
            await asyncio.gather(*tasks, return_exceptions=True)
        finally:
            # Nested so a second cancellation (emulator stopping) cannot skip it.
            for w in (c_writer, u_writer):
                if clean:
                    w.close()  # everything was drained already, so this cannot block
                else:
                    w.transport.abort()  # a stuck peer must not hang the shutdown


async def splice(
    a: tuple[asyncio.StreamReader, asyncio.StreamWriter], b: tuple[asyncio.StreamReader, asyncio.StreamWriter]
) -> None:
    """Relay both directions without impairment (the server side of the netns path)."""
    zero = DirectionModel(0.0)
    await relay_connection(a, b, zero, zero)
