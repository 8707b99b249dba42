"""The link emulator a benchmark uses: ``with emulated_link(profile, target) as (host, port)``.

Two modes, chosen at start:

* ``netns`` (root, iproute2; preferred): client -> relay on 127.0.0.1 (delay + jitter) -> TCP over
  a veth pair between two private namespaces (``tbf`` rate per direction, nftables random drop
  per direction, so loss costs real TCP retransmissions) -> splice -> target on 127.0.0.1.
* ``userspace`` (fallback): one relay on 127.0.0.1 that also shapes rate and turns loss into
  retransmission delay with the right probability (TCP cannot lose bytes end to end).

If tc or nft alone is missing, the netns mode keeps what works and does the rest in userspace.
The relay's event loop runs in a background thread, so synchronous clients can use it.
"""

from __future__ import annotations

import asyncio
import atexit
import logging
import random
import socket
import threading
import time
import weakref
from collections.abc import Iterator
from concurrent.futures import Future
from contextlib import contextmanager
from typing import Literal

from . import netns
from .accepting import Acceptor
from .profiles import LinkProfile, get_profile
from .relay import DirectionModel, RateClock, relay_connection, splice
from .schedule import LinkSchedule, LinkState

log = logging.getLogger("linkemu")

Mode = Literal["auto", "netns", "userspace"]
Address = tuple[str, int]
_START_TIMEOUT_S = 30.0

_live: weakref.WeakSet[LinkEmulator] = weakref.WeakSet()


@atexit.register
def _stop_all() -> None:
    # Last resort for emulators started without a `with` block and never stopped.
    for emu in list(_live):
        emu.stop()


class LinkEmulator:
    """Relay that makes ``target`` look like it sits behind ``profile``'s link.

    After :meth:`start`, :attr:`mode` is ``passthrough`` (loopback profile: no relay),
    ``netns`` or ``userspace``; :attr:`kernel_rate` / :attr:`kernel_loss` say which
    impairments the kernel applies (the rest are done by the relay).

    ``handshake_rtt``: a relay answers the client's SYN locally, so ``connect()`` returns at
    once; to keep request timings right, no uplink byte of a new connection reaches the server
    before ``RTT + delay`` after accept, as if connect() had taken the missing round trip.

    ``schedule``: outages and changes of delay, jitter or loss over time (:mod:`linkemu.schedule`),
    counted from :attr:`started_at` (``time.monotonic()`` when the link came up, or, with
    ``hold_schedule``, when :meth:`start_schedule` is called: say once the client is streaming). An outage drops
    every packet both ways in the kernel (netns mode with nftables: TCP retransmits with its real
    backoff), or holds every chunk until the link is back (userspace).
    """

    def __init__(
        self,
        profile: LinkProfile | str,
        target: Address,
        *,
        listen: Address = ("127.0.0.1", 0),
        mode: Mode = "auto",
        seed: int | None = None,
        handshake_rtt: bool = True,
        schedule: LinkSchedule | None = None,
        hold_schedule: bool = False,
    ) -> None:
        self.profile = get_profile(profile) if isinstance(profile, str) else profile
        self.schedule = schedule or LinkSchedule()
        self.hold_schedule = hold_schedule
        self.started_at: float | None = None
        self.state = LinkState(self.profile)
        self.target = (target[0], int(target[1]))
        self.listen = listen
        self.requested_mode = mode
        self.handshake_rtt = handshake_rtt
        self.mode: str | None = None
        self.kernel_rate = False
        self.kernel_loss = False
        self.address: Address | None = None
        self._rng = random.Random(seed)
        self._pair: netns.NetnsPair | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._acceptor: Acceptor | None = None  # made with the loop
        # Replaced in start() by the profile's models; zero-delay until then.
        self._up = DirectionModel(0.0)
        self._down = DirectionModel(0.0)
        self._ns_port = 0
        self._stopped = False
        self._lock = threading.Lock()
        self._schedule_task: asyncio.Task[None] | None = None

    # -- lifecycle ---------------------------------------------------------------------------

    def start(self) -> Address:
        """Set the link up and return the address clients should connect to."""
        if self.address is not None:
            return self.address
        if self.profile.is_passthrough and self.schedule.is_static and self.requested_mode == "auto":
            self.mode = "passthrough"
            self.address = self.target
            return self.address
        ns_listener = None
        try:
            ns_listener = self._setup_kernel()
            self._start_loop()
            assert self._loop is not None
            fut = asyncio.run_coroutine_threadsafe(self._serve(ns_listener), self._loop)
            self.address = fut.result(timeout=_START_TIMEOUT_S)
        except BaseException:
            # Includes KeyboardInterrupt during set-up: never leave namespaces behind.
            self.stop()
            if ns_listener is not None:
                ns_listener.close()
            raise
        _live.add(self)
        log.info(
            "link %s (%s mode, kernel rate=%s loss=%s): %s:%d -> %s:%d",
            self.profile.name,
            self.mode,
            self.kernel_rate,
            self.kernel_loss,
            *self.address,
            *self.target,
        )
        return self.address

    def stop(self) -> None:
        """Close every connection, stop the relay and delete namespaces. Idempotent; an
        emulator is not restartable (make a new one)."""
        with self._lock:
            if self._stopped:
                return
            self._stopped = True
        try:
            loop, thread = self._loop, self._thread
            if loop is not None and thread is not None and thread.is_alive():
                try:
                    asyncio.run_coroutine_threadsafe(self._shutdown(), loop).result(timeout=10)
                except Exception as exc:  # noqa: BLE001 - teardown must go on regardless
                    log.warning("relay shutdown: %r", exc)
                loop.call_soon_threadsafe(loop.stop)
                thread.join(timeout=10)
            elif loop is not None and not loop.is_closed():
                loop.close()  # the thread never started
        finally:
            if self._pair is not None:
                self._pair.destroy()
                self._pair = None
            _live.discard(self)

    def loss_stats(self) -> dict[str, tuple[int, int]]:
        """``{"up": (lost, packets), "down": ...}`` so far: kernel drops over veth packets in
        netns mode, else the userspace model's retransmission events over MSS segments."""
        if self._pair is not None and self.kernel_loss:
            return self._pair.loss_counters()
        if self.mode in ("netns", "userspace"):
            return {"up": (self._up.lost, self._up.segments), "down": (self._down.lost, self._down.segments)}
        return {"up": (0, 0), "down": (0, 0)}

    def elapsed(self) -> float:
        """Seconds since the link came up (the schedule's clock)."""
        if self.started_at is None:
            raise RuntimeError("the link is not started")
        return time.monotonic() - self.started_at

    def __enter__(self) -> Address:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- set-up ------------------------------------------------------------------------------

    def _setup_kernel(self) -> socket.socket | None:
        """Build the namespace pair when wanted and possible; return the server-side listener."""
        p = self.profile
        use_netns = False
        if self.requested_mode in ("auto", "netns"):
            caps = netns.detect_capabilities()
            if caps.netns:
                use_netns = True
                if caps.reason:
                    log.warning("%s", caps.reason)
            elif self.requested_mode == "netns":
                raise RuntimeError(f"netns mode unavailable: {caps.reason}")
            else:
                log.warning(
                    "netns mode unavailable (%s); falling back to the userspace "
                    "relay: loss becomes retransmission delay, rate is shaped per chunk",
                    caps.reason,
                )
        ns_listener = None
        if use_netns:
            netns.sweep_stale()
            self._pair = netns.NetnsPair.create()
            self.kernel_rate, self.kernel_loss = self._pair.shape(p, caps)
            ns_listener = self._pair.socket_in(self._pair.server_ns)
            ns_listener.bind((netns.SERVER_ADDR, 0))
            ns_listener.listen(512)
            ns_listener.setblocking(False)
            self._ns_port = ns_listener.getsockname()[1]
            # Start the client-side namespace thread now, not on the first connection (~ms).
            self._pair.socket_in(self._pair.client_ns).close()
            self.mode = "netns"
        else:
            self.mode = "userspace"
        self._up = self._model(p.rate_mbit_up)
        self._down = self._model(p.rate_mbit_down)
        return ns_listener

    def _model(self, rate_mbit: float | None) -> DirectionModel:
        p = self.profile
        rate = None if (self.kernel_rate or rate_mbit is None) else RateClock(rate_mbit * 1e6)
        loss = 0.0 if self.kernel_loss else p.loss_pct / 100
        # Even when tbf shapes the rate, the relay's queue is sized from it: an unbounded
        # relay queue in front of a slow uplink would add seconds of bufferbloat.
        nominal = None if rate_mbit is None else rate_mbit * 1e6
        return DirectionModel(
            p.delay_ms / 1000, p.jitter_ms / 1000, rate, loss, random.Random(self._rng.random()), nominal_bps=nominal
        )

    def _start_loop(self) -> None:
        self._loop = asyncio.new_event_loop()
        self._acceptor = acceptor = Acceptor(self._loop)
        ready = threading.Event()

        def run() -> None:
            loop = self._loop
            assert loop is not None
            asyncio.set_event_loop(loop)
            loop.call_soon(ready.set)
            try:
                loop.run_forever()
            finally:
                # Whatever _shutdown could not finish (it timed out, or never ran): cancel
                # it as asyncio.run does, close every accepted socket, then close the loop.
                pending = asyncio.all_tasks(loop)
                for task in pending:
                    task.cancel()
                loop.run_until_complete(asyncio.gather(*pending, return_exceptions=True))
                acceptor.close_listeners()
                acceptor.close_accepted()
                # abort() releases a socket in a callback on the next loop iteration.
                loop.run_until_complete(asyncio.sleep(0))
                loop.run_until_complete(loop.shutdown_asyncgens())
                loop.close()

        # Daemon: a benchmark that forgets stop() must still be able to exit (atexit cleans up).
        self._thread = threading.Thread(target=run, name=f"linkemu-{self.profile.name}", daemon=True)
        self._thread.start()
        if not ready.wait(_START_TIMEOUT_S):
            raise RuntimeError("relay event loop did not start")

    # -- event loop side ---------------------------------------------------------------------

    async def _serve(self, ns_listener: socket.socket | None) -> Address:
        assert self._acceptor is not None  # its own accept callbacks: see Acceptor
        if ns_listener is not None:
            self._acceptor.listen(ns_listener, self._on_ns_conn)
        host, port = self.listen
        family, type_, proto, _, sockaddr = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
        front = socket.socket(family, type_, proto)
        try:
            if port:  # a fixed port may be in TIME_WAIT; port 0 needs no reuse (and must never share a listener's)
                front.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            front.bind(sockaddr)
            front.listen(512)
            front.setblocking(False)
        except BaseException:
            front.close()
            raise
        self._acceptor.listen(front, self._on_client)
        bound = front.getsockname()
        if not self.hold_schedule:
            self._begin_schedule(asyncio.get_running_loop().time())  # time.monotonic(), the loop's clock
        return str(bound[0]), int(bound[1])

    def start_schedule(self, at: float | None = None) -> None:
        """Start the schedule's clock at ``at`` (``time.monotonic()``; default now), from the profile as given.
        Restarts it when it already runs."""
        if self._loop is None:
            raise RuntimeError("the link is not started")
        when = time.monotonic() if at is None else at
        asyncio.run_coroutine_threadsafe(self._restart_schedule(when), self._loop).result(timeout=_START_TIMEOUT_S)

    async def _restart_schedule(self, at: float) -> None:
        if self._schedule_task is not None:
            self._schedule_task.cancel()
            await asyncio.gather(self._schedule_task, return_exceptions=True)
        self.started_at = at
        await self._apply(LinkState(self.profile))
        self._begin_schedule(at)

    def _begin_schedule(self, at: float) -> None:
        self.started_at = at
        if self.schedule.is_static:
            return
        assert self._loop is not None and self._acceptor is not None
        task = self._loop.create_task(self._follow_schedule())
        self._schedule_task = task
        self._acceptor.keep(task)  # cancelled by _shutdown like a connection

    async def _follow_schedule(self) -> None:
        loop = asyncio.get_running_loop()
        assert self.started_at is not None
        for edge in self.schedule.edges():
            wait = self.started_at + edge - loop.time()
            if wait > 0:
                await asyncio.sleep(wait)
            await self._apply(self.schedule.state_at(self.profile, edge))

    async def _apply(self, state: LinkState) -> None:
        """Put the link into ``state``: delay and jitter in the relay, loss and outages in the kernel when it drops
        packets, else in the relay's model."""
        assert self.started_at is not None
        p = state.profile
        down_until = 0.0 if state.down_until is None or self.kernel_loss else self.started_at + state.down_until
        for model in (self._up, self._down):
            model.delay_s, model.jitter_s = p.delay_ms / 1000, p.jitter_ms / 1000
            model.down_until = down_until
            if not self.kernel_loss:
                model.loss = p.loss_pct / 100
        rates = (p.rate_mbit_up, p.rate_mbit_down)
        if rates != (self.state.profile.rate_mbit_up, self.state.profile.rate_mbit_down):
            if not await self._set_rates(rates):
                return
        if (
            self.kernel_loss
            and self._pair is not None
            and (state.down, p.loss_pct)
            != (
                self.state.down,
                self.state.profile.loss_pct,
            )
        ):
            try:
                await asyncio.to_thread(self._pair.set_drop_both, p.loss_pct, state.down)
            except netns.NetnsError as exc:
                log.warning("link %s: cannot apply %s: %s", self.profile.name, state, exc)
                return
        self.state = state
        log.info(
            "link %s: %s (delay %g ms, jitter %g ms, loss %g %%, up %s, down %s Mbit/s)",
            self.profile.name,
            "down" if state.down else "up",
            p.delay_ms,
            p.jitter_ms,
            p.loss_pct,
            "unshaped" if p.rate_mbit_up is None else f"{p.rate_mbit_up:g}",
            "unshaped" if p.rate_mbit_down is None else f"{p.rate_mbit_down:g}",
        )

    async def _set_rates(self, rates: tuple[float | None, float | None]) -> bool:
        """Each direction's rate (Mbit/s; None: as it was): tbf replaced in the kernel where it shapes, else the
        relay's clock; the relay's queue is sized from the new rate either way. False if the kernel refused."""
        for model, rate_mbit, (ns, dev) in zip((self._up, self._down), rates, self._shaped_devices(), strict=True):
            if rate_mbit is None:
                continue
            if self.kernel_rate and self._pair is not None:
                try:
                    await asyncio.to_thread(self._pair.add_tbf, ns, dev, rate_mbit)
                except netns.NetnsError as exc:
                    log.warning("link %s: cannot set the rate to %g Mbit/s: %s", self.profile.name, rate_mbit, exc)
                    return False
            elif model.rate is None:
                model.rate = RateClock(rate_mbit * 1e6)
            else:
                model.rate.rate_bps = rate_mbit * 1e6
            model.nominal_bps = rate_mbit * 1e6
        return True

    def _shaped_devices(self) -> tuple[tuple[str, str], tuple[str, str]]:
        """Where each direction is shaped in the kernel: the uplink leaves the client's end, the downlink the
        server's."""
        pair = self._pair
        if pair is None:
            return ("", ""), ("", "")
        return (pair.client_ns, pair.client_if), (pair.server_ns, pair.server_if)

    async def _open_upstream(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        if self._pair is None:
            return await asyncio.open_connection(*self.target)
        loop = asyncio.get_running_loop()
        pair = self._pair
        fut = pair.socket_future(pair.client_ns)
        try:
            sock = await asyncio.wrap_future(fut)
        except asyncio.CancelledError:
            # The worker may still hand over a socket nobody will use: close it on arrival.
            fut.add_done_callback(_close_result)
            raise
        try:
            sock.setblocking(False)
            await loop.sock_connect(sock, (netns.SERVER_ADDR, self._ns_port))
        except BaseException:
            sock.close()
            raise
        return await asyncio.open_connection(sock=sock)

    async def _on_client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        accepted = asyncio.get_running_loop().time()
        try:
            upstream = await self._open_upstream()
        except OSError as exc:
            log.warning("cannot reach %s:%d: %s", *self.target, exc)
            return
        # On a real link connect() returns after one RTT and the first request then takes one
        # more delay to arrive: that is the earliest the first uplink byte may leave.
        not_before = accepted + 3 * self._up.delay_s if self.handshake_rtt else 0.0
        await relay_connection((reader, writer), upstream, self._up, self._down, not_before)

    async def _on_ns_conn(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            upstream = await asyncio.open_connection(*self.target)
        except OSError as exc:
            log.warning("cannot reach %s:%d: %s", *self.target, exc)
            return
        await splice((reader, writer), upstream)

    async def _shutdown(self) -> None:
        assert self._acceptor is not None
        await self._acceptor.shutdown()


def _close_result(fut: Future[socket.socket]) -> None:
    if not fut.cancelled() and fut.exception() is None:
        fut.result().close()


@contextmanager
def emulated_link(
    profile: LinkProfile | str,
    target: Address,
    *,
    listen: Address = ("127.0.0.1", 0),
    mode: Mode = "auto",
    seed: int | None = None,
    handshake_rtt: bool = True,
    schedule: LinkSchedule | None = None,
) -> Iterator[Address]:
    """Emulate ``profile`` in front of ``target``; yield the ``(host, port)`` to connect to.

    Everything (relay thread, namespaces, veths, qdiscs, nft tables) is torn down on exit,
    including on exceptions and KeyboardInterrupt. ``mode``: ``auto`` prefers netns and falls
    back to userspace with a warning; ``netns`` raises if unavailable. ``schedule``: see
    :class:`LinkEmulator` (use the object to see its clock and state).
    """
    emu = LinkEmulator(
        profile, target, listen=listen, mode=mode, seed=seed, handshake_rtt=handshake_rtt, schedule=schedule
    )
    address = emu.start()
    try:
        yield address
    finally:
        emu.stop()
