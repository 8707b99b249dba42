"""A link: the client's connection to one netapp. It owns the session (its transport), the frame encoder, the
pacer, this netapp's clock estimate and the link's network samples, and it reconnects and moves by itself; what
happens on it reaches the client through `LinkEvents`, each call naming the link.

A netapp replica that is going away (draining) tells its robots to move (a `move` event on Socket.IO or `frames`,
HTTP 503 `draining`): the link opens a new session through the same URL, where the Service puts it on a ready replica.
Reconnecting is the link's alone, whatever the transport: after a dropped connection (`_on_lost`: the same transport
connects again, INIT and the session state restored), at `connect()`, after a move; each waits by the one
`netapp.reconnect.ReconnectPolicy`.
"""

from __future__ import annotations

import logging
import statistics
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import replace
from typing import Any, Protocol

from netapp.client.encoders import FrameEncoder
from netapp.client.errors import ConnectionLost, NetAppError, NetAppRefused
from netapp.client.hints import Hint, HintReader
from netapp.client.pacing import Pacer
from netapp.client.sizing import Size, to_source_coordinates
from netapp.client.timing import ClockOffsetEstimator, LatencyBreakdown, server_stamps
from netapp.client.transports import Transport, TransportCallbacks
from netapp.client.wire import WireSequencer
from netapp.frame import EncodedFrame
from netapp.protocol import ACCURACY_PROFILE_FIELD, HINT_FIELD, INPUT_SIZE_FIELD, WAKING_REASON
from netapp.reconnect import ReconnectPolicy

log = logging.getLogger(__name__)

RECONNECT_INTERVAL_S = 2.0  # a netapp that could not be reached at connect() is tried again this often
# A dropped connection is opened again after 0.5 s, then twice as long each time up to 5 s (python-socketio's own
# numbers, which the robot's Socket.IO sessions had before the link reconnected them).
DROPPED_FIRST_S, DROPPED_MAX_S = 0.5, 5.0
# A netapp being woken from zero (a `waking` refusal) refuses connections while it starts: tried again after the
# first, doubling up to the second (seconds), never backed off further.
WAKE_RETRY_S = (0.05, 0.2)
MOVE_RETRY_S = 0.1  # after a move, a new session that did not open is tried again after this, doubling each time
NETWORK_SAMPLES = 5
SIZES_KEPT = 256  # frames in flight whose sent size is remembered (more than any in-flight bound)

OpenSession = Callable[[str, TransportCallbacks], Transport]  # (url, callbacks) -> a transport, not connected yet


class LinkEvents(Protocol):
    """What the client hears from its links (from the links' and the transports' threads)."""

    def link_up(self, link: NetAppLink) -> None: ...
    def link_down(self, link: NetAppLink) -> None: ...  # closed or dropped: its frames in flight are lost
    def link_lost(self, link: NetAppLink) -> None: ...  # dropped while the client is open: it reconnects
    def link_moving(self, link: NetAppLink, reason: str) -> None: ...  # draining: a new session follows
    def result(self, link: NetAppLink, message: dict[str, Any]) -> None: ...
    def error(self, link: NetAppLink, message: dict[str, Any]) -> None: ...
    def superseded(self, link: NetAppLink, timestamp: int) -> None: ...
    def refused(self, reason: str) -> None: ...
    def state_to_restore(self) -> Any: ...
    def restored(self, ok: bool, message: str) -> None: ...


class NetAppLink:
    """One netapp: told of events through its methods and its transport's callbacks, never changed from outside."""

    def __init__(
        self,
        index: int,
        url: str,
        encoder: FrameEncoder,
        pacer: Pacer,
        open_session: OpenSession,
        events: LinkEvents,
        wire: WireSequencer,
        closed: threading.Event,
        hints: HintReader | None = None,
    ) -> None:
        self.index = index
        self.url = url
        self.encoder = encoder
        self.carrier: Transport | None = None
        # This netapp's clock relative to ours, for the latency breakdown (each netapp has its own clock; a new one
        # after a reconnect or a switch, which may reach another machine).
        self.clock = ClockOffsetEstimator()
        self._open_session = open_session
        self._events = events
        self._wire = wire
        self._closed = closed
        self._lock = threading.Lock()  # a leaf: the ledger asks `accepts` while claiming
        self._pacer = pacer  # how many frames may be in flight here, and when the next may go
        self._connected = False
        self._reported: dict[str, float] | None = None  # our last uplink/downlink to this netapp, told to its page
        # The link's share of the latency, recent samples: a result's latency minus the netapp's own time, or how
        # long a `deadline` drop took to come back (it leaves the netapp at once). Their median ignores a backlog.
        self._network: deque[float] = deque(maxlen=NETWORK_SAMPLES)
        self._moving = False  # a move to another replica is under way (the netapp is draining)
        self._move_again = False  # the session that move opens was told to move too
        self._hints = hints
        # What the netapp's processor consumes (its session info, then its results' hints): the robot sends no more.
        self.input_size: Size | None = None
        self.accuracy_profile: str | None = None  # the netapp's processor's, as it said (hints.py checks it)
        self.hint: Hint | None = None  # the latest valid hint from this netapp (next_frame_in_ms and all)
        # (sent size, source size) of each frame in flight, by timestamp: its boxes go back to the source's pixels
        # when its result comes, whatever the size is by then.
        self._sizes: OrderedDict[int, tuple[Size, Size]] = OrderedDict()

    @property
    def connected(self) -> bool:
        return self._connected

    @property
    def session_id(self) -> str | None:
        carrier = self.carrier
        return carrier.session_id if carrier is not None else None

    # -- the session -----------------------------------------------------------------------------------------------

    def open(self, retry_within_s: float = 0.0, dropped: Transport | None = None) -> None:
        """Open a session (`dropped`: on the transport whose connection dropped); raises NetAppError when the netapp
        cannot be reached, `NetAppRefused` when it refuses. A refusal that says when to try again (Retry-After) is
        tried again then, while that is within `retry_within_s` of now; after a netapp said it is waking (from zero),
        so is a port that refuses connections while it starts, on a short schedule (WAKE_RETRY_S)."""
        deadline = time.monotonic() + retry_within_s
        waking: ReconnectPolicy | None = None  # the schedule once the netapp said it is waking
        while True:
            try:
                return self._open_once(dropped)
            except NetAppError as exc:
                if isinstance(exc, NetAppRefused):
                    wait_s = exc.retry_after_s
                    if exc.reason == WAKING_REASON:
                        waking = waking or ReconnectPolicy(first_s=WAKE_RETRY_S[0], max_s=WAKE_RETRY_S[1])
                else:  # unreachable: worth another try only while the netapp is waking
                    wait_s = waking.next_s() if waking is not None else None
                if wait_s is None or time.monotonic() + wait_s > deadline:
                    raise
                log.debug("%s; trying again in %g s", exc, wait_s)
                if self._closed.wait(wait_s):
                    raise

    def _open_once(self, dropped: Transport | None = None) -> None:
        self.input_size, self.hint, self.accuracy_profile = None, None, None  # until this session's netapp says
        if dropped is not None:  # connected again as it was made (an RTP transport's counters go on)
            dropped.connect()
            return
        events = self._events
        callbacks = TransportCallbacks(
            on_ready=self._on_ready,
            on_lost=self._on_lost,
            on_result=lambda message: events.result(self, self._received(message)),
            on_error=lambda message: events.error(self, message),
            on_dropped=lambda timestamp: events.superseded(self, timestamp),
            on_refused=events.refused,
            on_move=self._on_move,
            on_session_info=self._on_session_info,
            state_to_restore=events.state_to_restore,  # each new session continues from the latest checkpoint
            on_restored=events.restored,
        )
        self.carrier = self._open_session(self.url, callbacks)
        try:
            self.carrier.connect()
        except BaseException:
            carrier, self.carrier = self.carrier, None
            carrier.close()
            raise

    def close(self) -> None:
        """End the session: its frames in flight are lost."""
        carrier, self.carrier = self.carrier, None
        if carrier is not None:
            carrier.close()
        self._went_down()

    def reconnect_in_background(self) -> None:
        threading.Thread(target=self.reconnect, name="netapp-connect", daemon=True).start()

    def reconnect(
        self,
        first_wait_s: float = RECONNECT_INTERVAL_S,
        max_wait_s: float = RECONNECT_INTERVAL_S,
        dropped: Transport | None = None,
    ) -> None:
        """Open a new session until one opens, the client is closed, or another one took over (a move, a switch):
        the first try after `first_wait_s`, then waiting twice as long each time, up to `max_wait_s`. `dropped`:
        the transport whose connection dropped, connected again."""
        policy = ReconnectPolicy(first_wait_s, max_wait_s, floor_s=MOVE_RETRY_S / 2)
        wait_s = policy.next_s()
        while not self._closed.wait(wait_s):
            if self.carrier is not dropped:  # a move, a switch or close() opened or ended the session meanwhile
                return
            try:
                self.open(dropped=dropped)
            except NetAppError as exc:  # e.g. after a move, the balancer has not yet seen the draining replica go
                log.debug("still cannot reach %s: %s", self.url, exc)
                wait_s = policy.next_s(exc.retry_after_s if isinstance(exc, NetAppRefused) else None)
                continue
            if self._closed.is_set():  # closed while this connection was being opened
                self.close()
            return

    def switch(self, url: str) -> None:
        """Move to another URL (an edge switchover): frames in flight here are lost."""
        log.info("switching netapp %s -> %s", self.url, url)
        self.close()
        self.url = url
        self.encoder.restart()  # a new remote decoder needs a keyframe first
        self.open()

    def _on_ready(self) -> None:
        self.encoder.restart()  # a new session decodes from a keyframe
        with self._lock:
            self.clock = ClockOffsetEstimator()  # a reconnect or a switch may reach another clock
            self._reported = None
            self._pacer.reset()  # another replica or netapp: its queue is another
            self._connected = True
        self._events.link_up(self)

    def _on_session_info(self, info: dict[str, Any]) -> None:
        """The netapp's word on the new session (before `_on_ready`): its processor's size, or none."""
        self.input_size = self._read_input_size(info.get(INPUT_SIZE_FIELD))
        if self._hints is not None:
            self.accuracy_profile = self._hints.read_profile_name(info.get(ACCURACY_PROFILE_FIELD), self.url)

    def _read_input_size(self, raw: Any) -> Size | None:
        return None if self._hints is None else self._hints.read_input_size(raw, self.url)

    def _on_lost(self) -> None:
        """The session's connection dropped: its transport connects again (from a thread of ours, not its own)."""
        self._went_down()
        if self._closed.is_set():
            return
        self._events.link_lost(self)
        carrier = self.carrier
        if carrier is not None:
            # a transport may try sooner than the default (a broker's: `BrokerTransport.reconnect_max_s`)
            max_s = getattr(carrier, "reconnect_max_s", DROPPED_MAX_S)
            args = (min(DROPPED_FIRST_S, max_s), max_s, carrier)
            threading.Thread(target=self.reconnect, args=args, name="netapp-reconnect", daemon=True).start()

    def _went_down(self) -> None:
        with self._lock:
            self._connected = False
        self._events.link_down(self)

    def _on_move(self, reason: str) -> None:
        """The netapp is draining: open a new session through the same URL; the newest frame waits for it."""
        with self._lock:
            if self._closed.is_set():
                return
            if self._moving:  # the session being opened is told to move too (it landed on the same replica)
                self._move_again = True
                return
            self._moving = True
        threading.Thread(target=self._move, args=(reason,), name="netapp-move", daemon=True).start()

    def _move(self, reason: str) -> None:
        try:
            while True:
                log.info("%s asked this robot to move (%s): reconnecting through the same URL", self.url, reason)
                with self._wire.between_frames():  # not in the middle of putting a frame on the old session
                    self.close()
                self._events.link_moving(self, reason)
                self.reconnect(first_wait_s=0.0)
                with self._lock:
                    if self._closed.is_set() or not self._move_again:
                        return
                    self._move_again = False
        finally:
            with self._lock:
                self._moving = False

    # -- frames ----------------------------------------------------------------------------------------------------

    def accepts(self, in_flight: int, now_ns: int) -> bool:
        """Whether a frame may go here now, with `in_flight` frames awaiting their results here."""
        with self._lock:
            return self._connected and self._pacer.allows(in_flight, now_ns)

    def hold_ns(self, now_ns: int) -> int:
        """How long the pacer holds the next frame back (0: not held, or not connected)."""
        with self._lock:
            return self._pacer.wait_ns(now_ns) if self._connected else 0

    def transmit(
        self,
        frame: EncodedFrame,
        deadline_ms: float | None,
        sizes: tuple[Size, Size] | None,
        trace: dict[str, str] | None = None,
    ) -> None:
        """Put an encoded frame on this session's wire, with its (sent, source) sizes (None: JPEG bytes as given)
        and its trace context (`netapp.client.tracing`); ConnectionLost when there is no session."""
        carrier = self.carrier
        if carrier is None:  # the session went (a move, a reconnect) while this frame waited for the wire
            raise ConnectionLost("no session")
        if sizes is not None:  # before it goes: its result may come back before `transmit` returns
            with self._lock:
                self._sizes[frame.timestamp] = sizes
                while len(self._sizes) > SIZES_KEPT:
                    self._sizes.popitem(last=False)
        carrier.transmit(self._addressed(frame, deadline_ms, trace))

    def _addressed(
        self, frame: EncodedFrame, deadline_ms: float | None, trace: dict[str, str] | None = None
    ) -> EncodedFrame:
        """The frame as this netapp gets it (one encoding serves every netapp, so it is copied, not changed): with
        what is left of the deadline for the netapp itself (the link takes its share), our previous uplink and
        downlink to it, for its page, and the frame's trace context, in its `meta`."""
        if deadline_ms is not None:
            frame = replace(frame, deadline_ms=round(max(1.0, deadline_ms - self.network_ms), 1))
        return frame.with_meta(**(trace or {}), latency=self._reported)

    # -- what comes back -------------------------------------------------------------------------------------------

    def _received(self, message: dict[str, Any]) -> dict[str, Any]:
        """A result as the robot sees it: boxes in its own frame's pixels; the netapp's hint taken in."""
        with self._lock:
            sizes = self._sizes.pop(message.get("timestamp"), None)  # type: ignore[arg-type]
        if sizes is not None:
            message = to_source_coordinates(message, *sizes)
        if self._hints is not None and HINT_FIELD in message:
            hint = self._hints.read(message[HINT_FIELD], sizes[1] if sizes else None, self.url)
            if hint is not None:
                self.hint = hint
                if hint.input_size is not None:
                    self.input_size = hint.input_size  # a netapp that changed its model, or spoke late: converge
        return message

    def pace(self, now_ns: int, message: dict[str, Any]) -> None:
        """A result for a frame still in flight here: the pacer learns the netapp's queue wait and batch time."""
        stamps = server_stamps(message)
        if stamps is not None:
            recv, before, after, _ = stamps
            next_ms = self.hint.next_frame_in_ms if self.hint is not None else None  # its hint (`_received`)
            with self._lock:
                next_turn_ns = None if next_ms is None else 1e6 * next_ms
                self._pacer.on_result(now_ns, before - recv, after - before, next_turn_ns, 1e6 * self.network_ms)

    def superseded(self) -> None:
        """The netapp has no room for two of our frames: one at a time."""
        with self._lock:
            self._pacer.on_superseded()

    def measure(self, sent_ns: int, now_ns: int, message: dict[str, Any]) -> LatencyBreakdown | None:
        """A result arrived: the link's share of its latency is sampled, and its breakdown returned."""
        latency_ms = (now_ns - sent_ns) / 1e6
        recv, send = message.get("recv_timestamp"), message.get("send_timestamp")
        if isinstance(recv, int) and isinstance(send, int) and send >= recv:  # the netapp held it this long
            self._network.append(max(0.0, latency_ms - (send - recv) / 1e6))
        parts = self.clock.breakdown(sent_ns, now_ns, message)
        if parts is not None:
            self._reported = {"uplink_ms": round(parts.uplink_ms, 2), "downlink_ms": round(parts.downlink_ms, 2)}
        return parts

    def deadline_drop(self, took_ms: float) -> None:
        """A `deadline` drop came back after `took_ms`: all of it was the link's."""
        self._network.append(took_ms)

    @property
    def network_ms(self) -> float:
        samples = list(self._network)
        return statistics.median(samples) if samples else 0.0
