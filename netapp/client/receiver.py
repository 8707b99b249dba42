"""What the client does with what comes back: from each link (a session up, down or moving; a result, an error or a
superseded frame) and from the local fallback. Each answer is settled in the ledger, measured on its link, told to
the policy and delivered; each outage reaches `on_error`."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Sequence
from typing import Any

from netapp.client.adapt.adapter import UplinkAdapter
from netapp.client.delivery import Checkpoints, Result, ResultDelivery
from netapp.client.fallback import LOCAL
from netapp.client.ledger import FALLBACK_TARGET, Ledger
from netapp.client.link import NetAppLink
from netapp.client.stats import ClientStats
from netapp.client.switching import Switcher, doing
from netapp.client.tracing import FrameTraces
from netapp.protocol import DEADLINE_REASON, STATE_KEY

log = logging.getLogger(__name__)


class Receiver:
    """The client's `LinkEvents`, and the fallback's callbacks."""

    def __init__(
        self,
        links: Sequence[NetAppLink],
        ledger: Ledger,
        switcher: Switcher,
        delivery: ResultDelivery,
        checkpoints: Checkpoints,
        stats: ClientStats,
        deadline_ms: float | None,
        pacing: bool,
        closed: threading.Event,
        adapter: UplinkAdapter | None = None,
        traces: FrameTraces | None = None,
    ) -> None:
        self._links = links
        self._ledger = ledger
        self._switcher = switcher
        self._delivery = delivery
        self._checkpoints = checkpoints
        self._stats = stats
        self._deadline_ms = deadline_ms
        self._pacing = pacing
        self._closed = closed
        self._adapter = adapter  # told of every answer, when the uplink adapts
        self._traces = traces  # sampled frames' spans are made as their answer is delivered

    # -- sessions --------------------------------------------------------------------------------------------------

    def link_up(self, link: NetAppLink) -> None:
        self._switcher.up(link.index)
        self._ledger.poke()  # a frame waiting for a slot may go there now
        self._switcher.update(f"{link.url} connected")

    def link_down(self, link: NetAppLink) -> None:
        self._switcher.down(link.index)
        self._ledger.lose_all_at(link.index)

    def link_lost(self, link: NetAppLink) -> None:
        mode = self._switcher.update(f"lost the connection to {link.url}")
        urls = tuple(n.url for n in self._links)
        self.outage(link, f"lost the connection to {link.url}; reconnecting. {doing(mode, urls)}", "disconnected")

    def link_moving(self, link: NetAppLink, reason: str) -> None:
        self._stats.add(moves=1)
        self._switcher.update(f"{link.url} is draining ({reason}): moving")

    def outage(self, link: NetAppLink, error: str, reason: str) -> None:
        self._stats.last_error = error
        self._delivery.error({"error": error, "reason": reason, "source": link.url, "state": self._switcher.mode.state})

    def refused(self, reason: str) -> None:
        self._stats.last_error = reason

    def state_to_restore(self) -> Any:
        return self._checkpoints.latest

    def restored(self, ok: bool, message: str) -> None:
        self._checkpoints.restored(ok, message)

    # -- answers from netapps --------------------------------------------------------------------------------------

    def result(self, link: NetAppLink, message: dict[str, Any]) -> None:
        now = time.monotonic_ns()
        timestamp = message.get("timestamp")
        held = self._ledger.holds(link.index, timestamp)  # not a stale result from before a reconnect
        if self._pacing and held:
            link.pace(now, message)  # before the slot is freed, so the next frame already goes at this pace
        sent_ns = self._ledger.sent_ns(timestamp) if held else None
        parts = link.measure(sent_ns, now, message) if sent_ns is not None else None
        learnt = None
        if self._adapter is not None and sent_ns is not None:
            # Before the slot is freed too: the frame waiting for it goes with what this result taught the adapter
            # (the first late result of a fall: a smaller frame, not one more big one behind it).
            learnt = self._adapter.result(timestamp, (now - sent_ns) / 1e6, parts)  # type: ignore[arg-type]
        sent = self._ledger.settle(link.index, timestamp)
        if sent is None:
            return  # a result for a frame already counted lost, or sent before a reconnect
        state = message.get(STATE_KEY)
        if state is not None:
            self._checkpoints.keep(timestamp, state)  # type: ignore[arg-type]
        latency_ms = (now - sent.sent_ns) / 1e6
        late = self._deadline_ms is not None and latency_ms > self._deadline_ms
        if parts is None:
            parts = link.measure(sent.sent_ns, now, message)
        if link.index not in sent.missed:
            self._switcher.outcome(link.index, on_time=not late, reason=f"{link.url} answered")
        result = Result(timestamp, message.get("detections", []), latency_ms, message, link.url, late, parts)  # type: ignore[arg-type]
        result.sent = learnt
        self._delivery.deliver(self._ledger.answer(sent), result)
        if self._traces is not None:
            self._traces.received(timestamp, now, message, link.clock.offset_ns, link.url)

    def error(self, link: NetAppLink, message: dict[str, Any]) -> None:
        link.encoder.note_error(message)  # before settling: the frame that takes the freed slot may react
        timestamp = message.get("timestamp")
        if message.get("reason") == DEADLINE_REASON:
            self._stats.add(deadline_dropped=1)
            sent_ns = self._ledger.sent_ns(timestamp)
            if sent_ns is not None:
                link.deadline_drop((time.monotonic_ns() - sent_ns) / 1e6)
            if self._adapter is not None and isinstance(timestamp, int):
                self._adapter.missed(timestamp)
        else:
            self._stats.add(errors=1)
            self._stats.last_error = str(message.get("error"))
        if timestamp is not None:
            sent = self._ledger.lose(link.index, timestamp)
            if sent is not None and link.index not in sent.missed:
                reason = f"{link.url}: {message.get('reason', 'error')}"
                self._switcher.outcome(link.index, on_time=False, reason=reason)
        self._delivery.error({**message, "source": link.url})
        if self._traces is not None:
            self._traces.failed(timestamp, time.monotonic_ns(), str(message.get("reason") or "error"), link.url)

    def superseded(self, link: NetAppLink, timestamp: int) -> None:
        """The netapp superseded the frame in its queue (HTTP 409, an error event with reason
        `superseded` on the others): its slot is
        free. Counted once, and only for a frame still waiting there (not one already counted lost)."""
        if self._pacing:
            link.superseded()  # before the slot frees
        if self._ledger.settle(link.index, timestamp) is not None:
            self._stats.add(dropped_server=1)

    # -- answers from the local fallback ---------------------------------------------------------------------------

    def local_result(self, message: dict[str, Any]) -> None:
        now = time.monotonic_ns()
        timestamp = message.get("timestamp")
        sent = self._ledger.settle(FALLBACK_TARGET, timestamp)
        if sent is None:
            return
        latency_ms = (now - sent.sent_ns) / 1e6
        late = self._deadline_ms is not None and latency_ms > self._deadline_ms
        result = Result(timestamp, message.get("detections", []), latency_ms, message, LOCAL, late)  # type: ignore[arg-type]
        self._delivery.deliver(self._ledger.answer(sent), result)

    def local_error(self, message: dict[str, Any]) -> None:
        self._ledger.lose(FALLBACK_TARGET, message.get("timestamp"))
        self._stats.add(errors=1)
        self._stats.last_error = str(message.get("error"))
        self._delivery.error(message)
