"""NetAppClient: send frames to one or several netapps over HTTP or Socket.IO (5G-ERA), get results by callback or
iterator, with a deadline, a policy over the netapps and a local fallback.

`send()` never waits for the network: with a free in-flight slot it encodes and hands the frame to the transport
at once; otherwise the newest frame waits in a one-frame slot (an older waiting frame is dropped and counted) until
fewer than `max_in_flight` frames await their results, and a sender thread encodes and transmits it then. So a
frame is dropped before it is encoded, never after (which matters for H.264, where a lost P-frame would corrupt
the remote decoder). When a netapp is the bottleneck (its results say that frames wait there longer than a batch),
the client sends it one frame at a time, each held back until shortly before the netapp's turn for it comes
(`netapp.client.pacing`; `pacing=False` turns it off), so no uplink is spent on frames the netapp would supersede.

The client owns that scheduling, the counters and the delivery of results; a frame encoder
(`netapp.client.encoders`) makes the bytes and a transport (`netapp.client.transports`) carries them:
"http" = HTTP + JPEG, "ws" = Socket.IO + JPEG, "h264" = Socket.IO + H.264.

With several URLs (in order of preference), a `Policy` (`netapp.client.policy`) says which netapps each frame goes
to: `primary` (fail over on errors or missed deadlines, and back), `hedge` (all; the first result wins, the others
are discarded and counted), `adaptive` (hedge only while the first netapp misses deadlines). With `fallback=` (any
SDK `Processor`, run on the robot by `netapp.client.local`), frames are processed locally while no netapp meets
the deadline. Every result says where it came from (`source`: the netapp's URL, or `local`) and whether it was
late; each change of what the client does is an event (`on_switch`), and every outage reaches `on_error`.

A netapp replica that is going away (draining) tells its robots to move (a Socket.IO `move` event, HTTP 503
`draining`): the client opens a new session with that netapp through the same URL, where the Service puts it on a
ready replica; that netapp's frames in flight are counted lost, and `stats.moves` counts the moves.

Every netapp result also carries its latency split into uplink, queue, inference and downlink (`breakdown`,
`netapp.client.timing`), from the clock offset of the netapp that answered: each netapp has its own estimate,
started afresh when its session opens again, and gets the robot's own uplink and downlink with the next frame,
for its live page.
"""

from __future__ import annotations

import logging
import queue
import statistics
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import requests

from netapp.client.encoders import EncodedFrame, Frame, FrameEncoder, H264StreamEncoder, JpegEncoder
from netapp.client.errors import ConnectionLost, NetAppError
from netapp.client.local import LOCAL, LocalProcessor
from netapp.client.pacing import Pacer
from netapp.client.policy import Mode, Policy
from netapp.client.stats import ClientStats
from netapp.client.timing import ClockOffsetEstimator, LatencyBreakdown, server_stamps
from netapp.client.transports import SessionSettings, Transport, TransportCallbacks
from netapp.client.transports.http import HttpTransport
from netapp.client.transports.socketio import SocketIOTransport
from netapp.client.urls import http_url
from netapp.protocol import DEADLINE_FIELD, DEADLINE_REASON, STATE_CHECKPOINT_ARG, STATE_KEY, TRANSPORTS

__all__ = ["NetAppClient", "NetAppError", "Result", "Switch"]

log = logging.getLogger(__name__)

# What carries each transport's frames (its encoder is chosen in `NetAppClient._new_encoder`).
CARRIERS: dict[str, Callable[[str, SessionSettings, TransportCallbacks], Transport]] = {
    "http": HttpTransport,
    "ws": SocketIOTransport,
    "h264": SocketIOTransport,
}
RECONNECT_INTERVAL_S = 2.0  # a netapp that could not be reached at connect() is tried again this often
MOVE_RETRY_S = 0.1  # after a move, a new session that did not open is tried again after this, doubling each time


@dataclass
class Result:
    timestamp: int
    detections: list[dict[str, Any]]
    latency_ms: float  # client send -> client receive
    message: dict[str, Any] = field(repr=False)  # the whole result message (server timestamps, extra fields)
    source: str = ""  # the URL of the netapp that answered, or "local"
    late: bool = False  # arrived after the deadline
    breakdown: LatencyBreakdown | None = None  # uplink / queue / inference / downlink (None: no netapp stamps)


@dataclass(frozen=True)
class Switch:
    """What the client does now (`on_switch`): its state, the netapps frames go to, the local fallback, and why."""

    state: str  # connected, hedging, fallback or reconnecting
    urls: tuple[str, ...]
    local: bool
    reason: str


@dataclass
class _NetApp:
    """One netapp the client talks to: its transport, encoder and frames awaiting its answer."""

    index: int
    url: str
    encoder: FrameEncoder
    pacer: Pacer  # how many frames may be in flight there, and when the next may go
    carrier: Transport | None = None
    connected: bool = False
    in_flight: dict[int, int] = field(default_factory=dict)  # timestamp -> send time (ns)
    moving: bool = False  # a move to another replica is under way (the netapp is draining)
    move_again: bool = False  # the session that move opens was told to move too
    # This netapp's clock relative to ours, for the latency breakdown (each netapp has its own clock; a new one
    # after a reconnect or a switch, which may reach another machine).
    clock: ClockOffsetEstimator = field(default_factory=ClockOffsetEstimator)
    reported: dict[str, float] | None = None  # our last uplink/downlink to this netapp, told to its page
    # The link's share of the latency, recent samples: a result's latency minus the netapp's own time, or how long a
    # `deadline` drop took to come back (it leaves the netapp at once). Their median ignores an outage's backlog.
    network_samples: deque[float] = field(default_factory=lambda: deque(maxlen=5))

    @property
    def network_ms(self) -> float:
        return statistics.median(self.network_samples) if self.network_samples else 0.0


@dataclass
class _Sent:
    """A frame handed to netapps (or the fallback) and not settled everywhere yet."""

    sent_ns: int
    waiting: set[int]  # netapp indexes (LOCAL_INDEX for the fallback) that may still answer
    answered: bool = False
    missed: set[int] = field(default_factory=set)  # netapps already counted as missing its deadline


LOCAL_INDEX = -1


class NetAppClient:
    """A robot's connection to one or several netapps. Thread-safe `send()`; use as a context manager."""

    def __init__(
        self,
        url: str | Sequence[str],
        transport: str = "ws",
        *,
        args: dict[str, Any] | None = None,
        robot_id: str | None = None,
        max_in_flight: int = 2,
        on_result: Callable[[Result], None] | None = None,
        on_error: Callable[[dict[str, Any]], None] | None = None,
        jpeg_quality: int = 85,
        connect_timeout_s: float = 10.0,
        result_timeout_s: float = 10.0,
        h264_options: dict[str, str] | None = None,
        checkpoint_every: int = 0,
        token: str | None = None,
        policy: str = "primary",
        deadline_ms: float | None = None,
        fallback: Any = None,
        on_switch: Callable[[Switch], None] | None = None,
        pacing: bool = True,
        websocket_first: bool = True,
    ) -> None:
        if transport not in TRANSPORTS:
            raise ValueError(f"transport must be one of {TRANSPORTS}, got {transport!r}")
        if max_in_flight < 1:
            raise ValueError("max_in_flight must be at least 1")
        if deadline_ms is not None and deadline_ms <= 0:
            raise ValueError("deadline_ms must be positive (or None for no deadline)")
        urls = [url] if isinstance(url, str) else list(url)
        if not urls:
            raise ValueError("give at least one netapp URL")
        self.transport = transport
        self.args = dict(args or {})
        if checkpoint_every:  # a stateful netapp then puts its session state in every Nth result
            self.args[STATE_CHECKPOINT_ARG] = checkpoint_every
        self.robot_id = robot_id
        self.max_in_flight = max_in_flight
        self.on_result = on_result
        self.on_error = on_error
        self.on_switch = on_switch
        self.jpeg_quality = jpeg_quality
        self.connect_timeout_s = connect_timeout_s
        self.result_timeout_s = result_timeout_s
        self.h264_options = h264_options
        self.token = token  # the netapps' bearer token, when they need one (the same for each)
        self.deadline_ms = deadline_ms
        self.pacing = pacing
        self.websocket_first = websocket_first  # Socket.IO: no long-polling start (`SessionSettings`)
        self.stats = ClientStats()
        self.policy = Policy(policy, len(urls), fallback=fallback is not None)
        self._jpeg = JpegEncoder(jpeg_quality)  # stateless: one encoding serves every netapp
        self._netapps = [_NetApp(i, http_url(u), self._new_encoder(), Pacer(max_in_flight)) for i, u in enumerate(urls)]
        self._local = (
            LocalProcessor(fallback, self._on_local_result, self._on_local_error, self.args)
            if fallback is not None
            else None
        )
        self._state: Any = None  # the latest session-state checkpoint (stateful netapps)
        self._state_timestamp = -1
        # Frames are encoded and put on the wire one at a time, in the order their slots were claimed (tickets):
        # the robot's thread and the sender thread both transmit, and an H.264 stream must not go back in time.
        self._wire = threading.Condition()
        self._tickets = 0  # claimed
        self._serving = 0  # the ticket whose frame goes on the wire next
        self._cond = threading.Condition()
        self._pending: tuple[int, Frame] | None = None
        self._sent: dict[int, _Sent] = {}  # by timestamp
        self._last_timestamp = 0
        self._newest: tuple[int, Frame] | None = None  # the newest frame sent: the fallback takes it over at once
        self._closed = threading.Event()
        self._mode = self.policy.mode()
        self._started = False  # switches are counted once connect() has returned
        self._results: queue.Queue[Result] = queue.Queue(maxsize=1000)
        self._sender: threading.Thread | None = None

    def _new_encoder(self) -> FrameEncoder:
        if self.transport == "h264":
            return H264StreamEncoder(self.h264_options)  # a stream per netapp: each decodes its own
        return self._jpeg

    # -- lifecycle -----------------------------------------------------------------------------------------------

    @property
    def urls(self) -> tuple[str, ...]:
        return tuple(n.url for n in self._netapps)

    @property
    def url(self) -> str:
        """The netapp in use: the first one frames go to (else the first given)."""
        mode = self._mode
        return self._netapps[mode.netapps[0]].url if mode.netapps else self._netapps[0].url

    @property
    def link_state(self) -> str:
        """What the client does: connected, hedging, fallback or reconnecting (`state` is a stateful netapp's
        session state)."""
        return self._mode.state

    def connect(self) -> NetAppClient:
        """Open a session with every netapp; raises NetAppError when none can be reached and there is no fallback.
        A netapp that cannot be reached now is tried again in the background."""
        if self._local is not None:
            try:
                self._local.start()
            except Exception as exc:  # a model that does not load: say so before anything is sent
                raise NetAppError(f"cannot load the local fallback: {exc}") from exc
        failures = []
        for netapp in self._netapps:
            try:
                self._open(netapp)
            except NetAppError as exc:
                failures.append(exc)
                self._report(netapp, f"{exc}; trying again every {RECONNECT_INTERVAL_S:g} s", "unreachable")
                threading.Thread(target=self._reconnect, args=(netapp,), name="netapp-connect", daemon=True).start()
        if len(failures) == len(self._netapps) and self._local is None:
            self.close()
            raise failures[0] if len(failures) == 1 else NetAppError("; ".join(str(f) for f in failures))
        if self._sender is None:
            self._sender = threading.Thread(target=self._send_loop, name="netapp-sender", daemon=True)
            self._sender.start()
        self._update_mode("connected")
        self._started = True
        return self

    def close(self) -> None:
        with self._cond:
            if self._closed.is_set():
                return
            self._closed.set()
            self._cond.notify_all()
        if self._sender is not None:
            self._sender.join(timeout=5)
        for netapp in self._netapps:
            self._disconnect(netapp)
        with self._wire:
            for netapp in self._netapps:
                netapp.encoder.close()
        if self._local is not None:
            self._local.close()

    def __enter__(self) -> NetAppClient:
        return self.connect()

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def switch_url(self, url: str) -> None:
        """Move the first netapp to another URL (an edge switchover): its frames in flight are counted lost."""
        url = http_url(url)
        netapp = self._netapps[0]
        if url == netapp.url:
            return
        log.info("switching netapp %s -> %s", netapp.url, url)
        self._disconnect(netapp)
        netapp.url = url
        netapp.encoder.restart()  # a new remote decoder needs a keyframe first
        self._open(netapp)

    def processor_info(self, timeout_s: float = 2.0) -> dict[str, Any] | None:
        """What the netapp in use serves (its `/v2` metadata's model: name, platform, ...), None if it does not
        say."""
        try:
            response = requests.get(f"{self.url}/v2", timeout=timeout_s)
            models = response.json().get("models") if response.ok else None
        except (requests.RequestException, ValueError, AttributeError):
            return None
        return models[0] if isinstance(models, list) and models and isinstance(models[0], dict) else None

    @property
    def connected(self) -> bool:
        return any(n.connected for n in self._netapps)

    @property
    def state(self) -> Any:
        """The latest session state a stateful netapp sent (`checkpoint_every`), or None. A new session (after
        `switch_url()`, a reconnect or a failover) gets it back with SET_STATE before its first frame, so a tracker
        there continues with the same track ids."""
        with self._cond:
            return self._state

    @property
    def session_id(self) -> str | None:
        """The first netapp's id of this robot's session (None before connecting)."""
        carrier = self._netapps[0].carrier
        return carrier.session_id if carrier is not None else None

    def _open(self, netapp: _NetApp) -> None:
        settings = SessionSettings(
            robot_id=self.robot_id,
            args=dict(self.args),
            max_in_flight=self.max_in_flight,
            connect_timeout_s=self.connect_timeout_s,
            result_timeout_s=self.result_timeout_s,
            token=self.token,
            websocket_first=self.websocket_first,
        )
        i = netapp.index
        callbacks = TransportCallbacks(
            on_ready=lambda: self._on_ready(i),
            on_lost=lambda: self._on_lost(i),
            on_result=lambda message: self._on_result_message(i, message),
            on_error=lambda message: self._on_error_message(i, message),
            on_dropped=lambda timestamp: self._on_dropped(i, timestamp),
            on_refused=self._on_refused,
            on_move=lambda reason: self._on_move(i, reason),
            state_to_restore=lambda: self.state,  # each netapp's new session continues from the latest checkpoint
            on_restored=self._on_restored,
        )
        netapp.carrier = CARRIERS[self.transport](netapp.url, settings, callbacks)
        try:
            netapp.carrier.connect()
        except BaseException:
            carrier, netapp.carrier = netapp.carrier, None
            carrier.close()
            raise

    def _reconnect(self, netapp: _NetApp, first_wait_s: float = RECONNECT_INTERVAL_S) -> None:
        """Open a new session with `netapp` until one opens or the client is closed: the first try after
        `first_wait_s`, then waiting twice as long each time, up to RECONNECT_INTERVAL_S."""
        wait_s = first_wait_s
        while not self._closed.wait(wait_s):
            try:
                self._open(netapp)
            except NetAppError as exc:  # e.g. after a move, the balancer has not yet seen the draining replica go
                log.debug("still cannot reach %s: %s", netapp.url, exc)
                wait_s = min(2 * max(wait_s, MOVE_RETRY_S / 2), RECONNECT_INTERVAL_S)
                continue
            if self._closed.is_set():  # closed while this connection was being opened
                self._disconnect(netapp)
            return

    def _disconnect(self, netapp: _NetApp) -> None:
        carrier, netapp.carrier = netapp.carrier, None
        if carrier is not None:
            carrier.close()
        self._lose_in_flight(netapp)

    # -- sending ---------------------------------------------------------------------------------------------

    def send(self, frame: Frame, timestamp: int | None = None) -> int:
        """Queue a frame (BGR array, or JPEG bytes for http/ws); returns its timestamp, the key of its result."""
        self._netapps[0].encoder.check(frame)
        with self._cond:
            if self._closed.is_set():
                raise NetAppError("the client is closed")
            if timestamp is None:
                timestamp = max(time.time_ns(), self._last_timestamp + 1)
            self._last_timestamp = max(self._last_timestamp, timestamp)
            self.stats.add(offered=1)
            if self.stats.frame_size is None and isinstance(frame, np.ndarray):
                self.stats.frame_size = (frame.shape[1], frame.shape[0])
            claim = self._claim(timestamp, frame) if self._pending is None else None
            if claim is None:  # no free slot where the frame should go: it waits, newest wins
                if self._pending is not None:
                    self.stats.add(dropped_client=1)
                self._pending = (timestamp, frame)
                self._cond.notify_all()
        if claim is not None:  # a free slot: transmit from this thread, sparing a thread hop on the latency path
            self._transmit(timestamp, frame, *claim)
        return timestamp

    def _claim(self, timestamp: int, frame: Frame) -> tuple[list[int], int] | None:
        """With the lock held: take the slots where the frame goes now (netapp indexes, LOCAL_INDEX) and its turn on
        the wire; None while it must wait."""
        now = time.monotonic_ns()
        route = self.policy.route(now)
        targets = [
            i
            for i in (*route.netapps, *route.probes)
            if self._netapps[i].connected and self._netapps[i].pacer.allows(len(self._netapps[i].in_flight), now)
        ]
        if route.local:
            targets.append(LOCAL_INDEX)
        if not targets:
            return None
        self._sent[timestamp] = _Sent(now, set(targets))
        self._newest = (timestamp, frame)
        for i in targets:
            if i != LOCAL_INDEX:
                self._netapps[i].in_flight[timestamp] = now
        self._tickets += 1
        return targets, self._tickets - 1

    def _send_loop(self) -> None:
        tick = 0.5 if self.deadline_ms is None else min(0.5, self.deadline_ms / 4000)
        while True:
            with self._cond:
                if self._closed.is_set():
                    return
                claim = self._claim(*self._pending) if self._pending is not None else None
                if claim is not None:
                    (timestamp, frame), self._pending = self._pending, None
                else:
                    self._cond.wait(timeout=self._wait_s(tick))
                    missed = self._expire()
            if claim is not None:
                self._transmit(timestamp, frame, *claim)
            elif missed:
                self._update_mode("deadlines missed")

    def _wait_s(self, tick: float) -> float:
        """With the lock held: how long the sender may sleep, at most until a paced netapp takes the next frame."""
        if self._pending is None:
            return tick
        now = time.monotonic_ns()
        waits = [n.pacer.wait_ns(now) for n in self._netapps if n.connected]
        held = [w for w in waits if w > 0]
        return min(tick, min(held) / 1e9) if held else tick

    def _transmit(self, timestamp: int, frame: Frame, targets: list[int], ticket: int) -> None:
        if LOCAL_INDEX in targets:
            assert self._local is not None
            self._local.submit(timestamp, frame)
        with self._wire:
            self._wire.wait_for(lambda: self._serving == ticket)
            try:
                self._put_on_wire(timestamp, frame, targets)
            finally:
                self._serving += 1
                self._wire.notify_all()

    def _put_on_wire(self, timestamp: int, frame: Frame, targets: list[int]) -> None:
        encoded: dict[int, EncodedFrame | None] = {}  # by encoder, so one JPEG serves every netapp
        for i in targets:
            if i == LOCAL_INDEX:
                continue
            netapp = self._netapps[i]
            try:
                key = id(netapp.encoder)
                if key not in encoded:
                    encoded[key] = netapp.encoder.encode(timestamp, frame)
                message = encoded[key]
                if message is None:  # the encoder is still buffering: no bytes for this frame yet
                    self._settle(i, timestamp)
                    continue
                self.stats.add(sent=1, bytes_sent=len(message.data))
                carrier = netapp.carrier
                if carrier is None:  # the session went (a move, a reconnect) while this frame waited for the wire
                    raise ConnectionLost("no session")
                carrier.transmit(self._for_netapp(netapp, message))
            except ConnectionLost:  # lost like the frames in flight there, not an error
                self._lose(i, timestamp)
            except Exception as exc:  # counted, never raised into the robot's loop or the sender thread
                log.warning("send to %s failed: %s", netapp.url, exc)
                self._settle(i, timestamp)
                self.stats.add(errors=1)
                self.stats.last_error = str(exc)
                self._outcome(i, timestamp, on_time=False, reason=f"{netapp.url}: send failed")

    def _for_netapp(self, netapp: _NetApp, frame: EncodedFrame) -> EncodedFrame:
        """The frame as this netapp gets it (one encoding serves every netapp, so it is copied, not changed): with
        what is left of the deadline for the netapp itself (the link takes its share), and our previous uplink and
        downlink to it, for its page."""
        extra: dict[str, Any] = {}
        if self.deadline_ms is not None:
            extra[DEADLINE_FIELD] = round(max(1.0, self.deadline_ms - netapp.network_ms), 1)
        if netapp.reported is not None:
            extra["metadata"] = {"latency": netapp.reported}
        return EncodedFrame(frame.codec, {**frame.message, **extra}) if extra else frame

    def _miss_after_ns(self) -> float:
        """When a frame still waiting at a netapp counts as a miss there: at its deadline, or with a fallback, once
        there is just time left for the robot to process it (so the fallback can still answer in time)."""
        assert self.deadline_ms is not None
        local_ms = self._local.expected_ms if self._local is not None else 0.0
        return max(self.deadline_ms / 2, self.deadline_ms - local_ms) * 1e6

    def _expire(self) -> bool:
        """Called with the lock held: a frame past its deadline is a miss where it waits (its result may still come,
        late); one past `result_timeout_s` is lost there, freeing its slot. True when a deadline was missed."""
        now = time.monotonic_ns()
        timeout_ns = int(self.result_timeout_s * 1e9)
        missed = False
        for timestamp, sent in list(self._sent.items()):
            age = now - sent.sent_ns
            if self.deadline_ms is not None and age > self._miss_after_ns():
                for i in sent.waiting - sent.missed - {LOCAL_INDEX}:
                    sent.missed.add(i)
                    self.policy.outcome(i, on_time=False)
                    missed = True
            if age > timeout_ns:
                for i in sent.waiting - {LOCAL_INDEX}:
                    self._netapps[i].in_flight.pop(timestamp, None)
                sent.waiting.clear()
                if not sent.answered:
                    self.stats.add(lost=1)
                del self._sent[timestamp]
                self._cond.notify_all()
        return missed

    def _settle(self, i: int, timestamp: int | None) -> _Sent | None:
        """Netapp `i` (or the fallback) is done with a frame; returns the frame's record, None if it was not
        waiting there. A frame nobody answered and nobody still holds is counted lost."""
        with self._cond:
            if i != LOCAL_INDEX:
                self._netapps[i].in_flight.pop(timestamp, None)
            sent = self._sent.get(timestamp)
            if sent is None or i not in sent.waiting:
                return None
            sent.waiting.discard(i)
            if not sent.waiting:
                del self._sent[timestamp]
            self._cond.notify_all()
            return sent

    def _lose(self, i: int, timestamp: int | None) -> _Sent | None:
        """Netapp `i` (or the fallback) will not answer a frame: settled there, and counted lost when nobody
        answered it and nobody else still holds it. Returns the frame's record (None if it was not waiting there)."""
        sent = self._settle(i, timestamp)
        if sent is not None and not sent.waiting and not sent.answered:
            self.stats.add(lost=1)
        return sent

    # -- what the transports and the fallback report ---------------------------------------------------------------

    def _on_ready(self, i: int) -> None:
        netapp = self._netapps[i]
        netapp.encoder.restart()  # a new session decodes from a keyframe
        netapp.clock = ClockOffsetEstimator()  # a reconnect or a switch may reach another clock
        netapp.reported = None
        with self._cond:
            netapp.pacer.reset()  # another replica or netapp: its queue is another
            netapp.connected = True
            self.policy.up(i)
            self._cond.notify_all()
        self._update_mode(f"{netapp.url} connected")

    def _on_lost(self, i: int) -> None:
        netapp = self._netapps[i]
        self._lose_in_flight(netapp)
        if self._closed.is_set():
            return
        mode = self._update_mode(f"lost the connection to {netapp.url}")
        self._report(netapp, f"lost the connection to {netapp.url}; reconnecting. {_doing(mode, self)}", "disconnected")

    def _lose_in_flight(self, netapp: _NetApp) -> None:
        """The connection dropped or was closed: frames in flight there will get no result."""
        with self._cond:
            netapp.connected = False
            self.policy.down(netapp.index)
            timestamps = list(netapp.in_flight)
        for timestamp in timestamps:
            self._lose(netapp.index, timestamp)

    def _on_result_message(self, i: int, message: dict[str, Any]) -> None:
        now = time.monotonic_ns()
        timestamp = message.get("timestamp")
        stamps = server_stamps(message)
        if self.pacing and stamps is not None:
            recv, before, after, _ = stamps
            with self._cond:  # before the slot is freed, so the next frame already goes at the pace learnt here
                if timestamp in self._netapps[i].in_flight:  # not a stale result from before a reconnect
                    self._netapps[i].pacer.on_result(now, before - recv, after - before)
        sent = self._settle(i, timestamp)
        if sent is None:
            return  # a result for a frame already counted lost, or sent before a reconnect
        state = message.get(STATE_KEY)
        if state is not None:
            self._keep_state(timestamp, state)
        latency_ms = (now - sent.sent_ns) / 1e6
        late = self.deadline_ms is not None and latency_ms > self.deadline_ms
        netapp = self._netapps[i]
        server_ns = _server_time_ns(message)
        if server_ns is not None:
            netapp.network_samples.append(max(0.0, latency_ms - server_ns / 1e6))
        parts = netapp.clock.breakdown(sent.sent_ns, now, message)
        if parts is not None:
            netapp.reported = {"uplink_ms": round(parts.uplink_ms, 2), "downlink_ms": round(parts.downlink_ms, 2)}
        if i not in sent.missed:
            self._outcome(i, timestamp, on_time=not late, reason=f"{netapp.url} answered")
        detections = message.get("detections", [])
        self._deliver(sent, Result(timestamp, detections, latency_ms, message, netapp.url, late, parts))

    def _on_local_result(self, message: dict[str, Any]) -> None:
        now = time.monotonic_ns()
        timestamp = message.get("timestamp")
        sent = self._settle(LOCAL_INDEX, timestamp)
        if sent is None:
            return
        latency_ms = (now - sent.sent_ns) / 1e6
        late = self.deadline_ms is not None and latency_ms > self.deadline_ms
        self._deliver(sent, Result(timestamp, message.get("detections", []), latency_ms, message, LOCAL, late))

    def _deliver(self, sent: _Sent, result: Result) -> None:
        with self._cond:
            first, sent.answered = not sent.answered, True
        if not first:  # another netapp (or the fallback) answered this frame already
            self.stats.add(discarded=1)
            return
        self.stats.add_result(result.latency_ms, result.detections, result.source, result.late, result.breakdown)
        if self.on_result is not None:
            try:
                self.on_result(result)
            except Exception:
                log.exception("on_result callback failed")
            return
        try:
            self._results.put_nowait(result)
        except queue.Full:  # a robot that never reads must not grow memory: keep the newest
            self._results.get_nowait()
            self._results.put_nowait(result)

    def _on_error_message(self, i: int, message: dict[str, Any]) -> None:
        netapp = self._netapps[i]
        netapp.encoder.note_error(message)  # before settling: the frame that takes the freed slot may react
        timestamp = message.get("timestamp")
        if message.get("reason") == DEADLINE_REASON:
            self.stats.add(deadline_dropped=1)
            sent = self._sent.get(timestamp)
            if sent is not None:
                netapp.network_samples.append((time.monotonic_ns() - sent.sent_ns) / 1e6)
        else:
            self.stats.add(errors=1)
            self.stats.last_error = str(message.get("error"))
        if timestamp is not None:
            sent = self._lose(i, timestamp)
            if sent is not None and i not in sent.missed:
                self._outcome(i, timestamp, on_time=False, reason=f"{netapp.url}: {message.get('reason', 'error')}")
        self._call_on_error({**message, "source": netapp.url})

    def _on_local_error(self, message: dict[str, Any]) -> None:
        self._lose(LOCAL_INDEX, message.get("timestamp"))
        self.stats.add(errors=1)
        self.stats.last_error = str(message.get("error"))
        self._call_on_error(message)

    def _on_dropped(self, i: int, timestamp: int) -> None:
        """Netapp `i` superseded the frame in its queue (HTTP 409, Socket.IO data_error `superseded`): its slot is
        free. Counted once, and only for a frame still waiting there (not one already counted lost)."""
        if self.pacing:
            with self._cond:  # the netapp has no room for two of our frames: one at a time, before the slot frees
                self._netapps[i].pacer.on_superseded()
        if self._settle(i, timestamp) is not None:
            self.stats.add(dropped_server=1)

    def _on_move(self, i: int, reason: str) -> None:
        """Netapp `i` is draining: open a new session with it through the same URL, where the Service puts it on a
        ready replica. Its frames in flight are counted lost; the newest frame waits for the new session."""
        netapp = self._netapps[i]
        with self._cond:
            if self._closed.is_set():
                return
            if netapp.moving:  # the session being opened is told to move too (it landed on the same replica)
                netapp.move_again = True
                return
            netapp.moving = True
        threading.Thread(target=self._move, args=(netapp, reason), name="netapp-move", daemon=True).start()

    def _move(self, netapp: _NetApp, reason: str) -> None:
        try:
            while True:
                self.stats.add(moves=1)
                log.info("%s asked this robot to move (%s): reconnecting through the same URL", netapp.url, reason)
                with self._wire:  # not in the middle of putting a frame on the old session's wire
                    self._disconnect(netapp)
                self._update_mode(f"{netapp.url} is draining ({reason}): moving")
                self._reconnect(netapp, first_wait_s=0.0)
                with self._cond:
                    if self._closed.is_set() or not netapp.move_again:
                        return
                    netapp.move_again = False
        finally:
            with self._cond:
                netapp.moving = False

    def _on_refused(self, reason: str) -> None:
        self.stats.last_error = reason

    def _outcome(self, i: int, timestamp: int | None, on_time: bool, reason: str) -> None:
        with self._cond:
            self.policy.outcome(i, on_time)
        self._update_mode(reason)

    # -- what the client does, and telling the robot ---------------------------------------------------------------

    def _update_mode(self, reason: str) -> Mode:
        """After the policy learned something: when what the client does changed, count it and tell the robot."""
        with self._cond:
            mode = self.policy.mode()
            changed, self._mode = mode != self._mode, mode
            takeover = self._take_over_newest() if changed and mode.local else None
        if takeover is not None and self._local is not None:
            self._local.submit(*takeover)
        if changed:
            switch = Switch(mode.state, tuple(self._netapps[i].url for i in mode.netapps), mode.local, reason)
            if self._started:
                self.stats.add(switches=1)
            log.info("%s: now %s", reason, _doing(mode, self))
            if self.on_switch is not None:
                try:
                    self.on_switch(switch)
                except Exception:
                    log.exception("on_switch callback failed")
        return mode

    def _take_over_newest(self) -> tuple[int, Frame] | None:
        """With the lock held, as the fallback starts: the newest frame sent, if no one answered it yet and there is
        still time, goes to the fallback too (it would otherwise wait for the next frame)."""
        if self._newest is None or self.deadline_ms is None:
            return None
        timestamp, frame = self._newest
        sent = self._sent.get(timestamp)
        if sent is None or sent.answered or LOCAL_INDEX in sent.waiting:
            return None
        if time.monotonic_ns() - sent.sent_ns > self.deadline_ms * 1e6:
            return None
        sent.waiting.add(LOCAL_INDEX)
        return timestamp, frame

    def _report(self, netapp: _NetApp, error: str, reason: str) -> None:
        self.stats.last_error = error
        self._call_on_error({"error": error, "reason": reason, "source": netapp.url, "state": self.link_state})

    def _call_on_error(self, message: dict[str, Any]) -> None:
        if self.on_error is not None:
            try:
                self.on_error(message)
            except Exception:
                log.exception("on_error callback failed")

    def _keep_state(self, timestamp: int, state: Any) -> None:
        with self._cond:
            if timestamp > self._state_timestamp:  # results may arrive out of order: keep the newest frame's
                self._state, self._state_timestamp = state, timestamp
        self.stats.add(checkpoints=1)

    def _on_restored(self, ok: bool, message: str) -> None:
        if ok:
            self.stats.add(restores=1)
        else:
            self.stats.add(errors=1)
            self.stats.last_error = f"the session state was not restored: {message}"

    # -- results ---------------------------------------------------------------------------------------------

    def results(self, timeout: float | None = None) -> Iterator[Result]:
        """Results as they arrive; stops after `timeout` seconds without one (None: until closed)."""
        while True:
            try:
                yield self._results.get(timeout=timeout if timeout is not None else 0.5)
            except queue.Empty:
                if timeout is not None or self._closed.is_set():
                    return

    def wait_idle(self, timeout_s: float = 10.0) -> bool:
        """Wait until nothing is pending or in flight (e.g. before reading the last results)."""
        deadline = time.monotonic() + timeout_s
        missed = idle = False
        with self._cond:
            while not (idle := self._pending is None and not self._sent) and time.monotonic() < deadline:
                self._cond.wait(timeout=min(deadline - time.monotonic(), 0.2))
                missed |= self._expire()
        if missed:
            self._update_mode("deadlines missed")
        return idle


def _server_time_ns(message: dict[str, Any]) -> int | None:
    """How long the netapp held the frame (receive to send, its own clock), from the result message."""
    recv, send = message.get("recv_timestamp"), message.get("send_timestamp")
    return send - recv if isinstance(recv, int) and isinstance(send, int) and send >= recv else None


def _doing(mode: Mode, client: NetAppClient) -> str:
    """What the client does, in words, for on_error and the log."""
    urls = ", ".join(client.urls[i] for i in mode.netapps)
    if mode.local:
        return f"processing frames locally ({mode.state})" + (f" while trying {urls}" if urls else "")
    if not mode.netapps:
        return "no netapp is connected (reconnecting)"
    return f"frames go to {urls} ({mode.state})"
