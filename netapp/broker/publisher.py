"""Results to one broker, at least once, on the event loop (docs/broker.md#delivery).

`offer` never waits: it puts the message in the bounded `Backlog` and wakes the sender. The sender (`run`, one task)
connects, sends a batch, and forgets it only once the broker confirmed it; a batch that fails goes back to the front
and the link is opened again with backoff and jitter (`netapp.backoff`). So a broker that is down at start-up, or
goes away mid-stream, delays nothing else: robots are served meanwhile, their results wait within the backlog's
bounds, and what overflows is counted by reason (and said once per outage in the log). The log says one line when
the broker is lost and one when it is back, with how long it was away.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

from netapp.backoff import Outage, backoff_s
from netapp.broker.address import BrokerAddress
from netapp.broker.backlog import Backlog, Outgoing
from netapp.broker.link import BrokerLink
from netapp.broker.links import link_for

log = logging.getLogger(__name__)

BATCH = 256  # messages in one batch: one round of confirms
BATCH_BYTES = 4 * 2**20
SEND_TIMEOUT_S = 15.0  # a batch not confirmed within this counts as a lost broker
FIRST_RETRY_S = 0.1
RETRY_CAP_S = 2.0  # a broker that is back is used again within about this (the 2 s)
CLOSE_FLUSH_S = 2.0  # what still waits at shutdown gets this long to go


@dataclass
class PublisherEvents:
    """Where a publisher reports what it did (the netapp's metrics); each call is cheap and never raises."""

    published: Callable[[int], None] = lambda count: None  # messages the broker confirmed
    dropped: Callable[[str], None] = lambda reason: None  # one message lost from the backlog, and why
    connected: Callable[[bool], None] = lambda up: None
    waiting: Callable[[int, int], None] = lambda count, size: None  # messages and bytes in the backlog now


class Publisher:
    """One broker's sender. `start()` on the event loop, `offer(...)` from it, `close()` at shutdown."""

    def __init__(
        self,
        address: BrokerAddress,
        link: Callable[[BrokerAddress], BrokerLink] = link_for,
        events: PublisherEvents | None = None,
    ) -> None:
        self.address = address
        self.name = address.redacted()
        self.backlog = Backlog(address.buffer, address.buffer_bytes)
        self.events = events or PublisherEvents()
        self.outage = Outage(self.name, kind="broker", cap_s=RETRY_CAP_S)
        self.published = 0
        self._make_link = link
        self._link: BrokerLink | None = None
        self._wake = asyncio.Event()
        self._task: asyncio.Task | None = None
        self._closing = False
        self._overflow_told = False  # the backlog's overflow was said in this outage

    def start(self) -> None:
        self._task = asyncio.get_running_loop().create_task(self.run(), name=f"publish {self.name}")

    def offer(self, topic: str, body: bytes, key: str | None = None, headers: dict[str, str] | None = None) -> None:
        """Queue one message (never waits; what the backlog's bounds cost is counted)."""
        for reason in self.backlog.offer(Outgoing(topic, body, key, headers)):
            self.events.dropped(reason)
            if not self._overflow_told:
                self._overflow_told = True
                log.warning(
                    "broker %s: its buffer is full (%d results or %.3g MiB): dropping the oldest (%s), counted in "
                    "netapp_broker_dropped_total; said once until it is back",
                    self.name,
                    self.backlog.max_count,
                    self.backlog.max_bytes / 2**20,
                    reason,
                )
        self.events.waiting(len(self.backlog), self.backlog.bytes)
        self._wake.set()

    @property
    def connected(self) -> bool:
        return self._link is not None

    async def run(self) -> None:
        while not self._closing:
            if self._link is None and not await self._connect():
                continue
            if not self.backlog.waiting:
                self._wake.clear()
                await self._wake.wait()
                continue
            await self._send()

    async def _connect(self) -> bool:
        link = self._make_link(self.address)
        try:
            await asyncio.wait_for(link.connect(), SEND_TIMEOUT_S)
        except Exception as exc:  # noqa: BLE001 (any failure to connect is an outage, said once)
            await link.close()
            await self._lost(_why(exc, self.address.password))
            return False
        self._link = link
        line = self.outage.connected(time.monotonic())
        if line:
            log.info("%s%s", line, self._dropped_note())
        self._overflow_told = False
        self.events.connected(True)
        return True

    async def _send(self) -> None:
        batch = self.backlog.take(BATCH, BATCH_BYTES)
        try:
            await asyncio.wait_for(self._link.publish(batch), SEND_TIMEOUT_S)
        except Exception as exc:  # noqa: BLE001 (unconfirmed: sent again once the broker is back)
            self.backlog.restore()
            link, self._link = self._link, None
            self.events.connected(False)
            await link.close()
            await self._lost(_why(exc, self.address.password))
            return
        self.backlog.confirm()
        self.published += len(batch)
        self.events.published(len(batch))
        self.events.waiting(len(self.backlog), self.backlog.bytes)

    async def _lost(self, why: str) -> None:
        line = self.outage.failed(time.monotonic(), why)
        if line:
            log.warning("%s; results wait in its buffer meanwhile", line)
        if not self._closing:
            await asyncio.sleep(backoff_s(self.outage.attempts - 1, FIRST_RETRY_S, RETRY_CAP_S))

    def _dropped_note(self) -> str:
        dropped = sum(self.backlog.dropped.values())
        return f" ({dropped} results dropped from its buffer so far)" if dropped else ""

    async def close(self, flush_s: float = CLOSE_FLUSH_S) -> None:
        """Send what waits for up to `flush_s` while connected, then stop and close the link."""
        deadline = time.monotonic() + flush_s
        while self._link is not None and len(self.backlog) and time.monotonic() < deadline:
            await asyncio.sleep(0.01)  # the sender is draining it: wait with a deadline
        self._closing = True
        if self._task is not None:
            self._task.cancel()
            try:
                await self._task
            except asyncio.CancelledError:
                pass
        if self._link is not None:
            await self._link.close()
            self._link = None
        if len(self.backlog):
            log.warning("broker %s: %d results not published at shutdown", self.name, len(self.backlog))


def _why(exc: BaseException, secret: str | None) -> str:
    """An exception as a short reason for the log (its class when it says nothing), `secret` never in it (a client
    library may quote the URL it was given)."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    if secret:
        text = text.replace(secret, "***")
    return f"{type(exc).__name__}: {text}"[:200] if text else type(exc).__name__
