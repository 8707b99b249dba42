"""Frames through a broker (docs/broker.md#frames-through-a-broker): the robot's end, for `amqp://`, `mqtt://` and
`kafka://` URLs (`amqp://HOST/?netapp=NAME`).

Each frame is the `frames` wire's binary message (`netapp.framing.pack_frame`, the one `EncodedFrame`), published to
the netapp's work queue with this session's envelope (`netapp.broker.frames.Envelope`: the robot's id, this session's
own id, its reply address, when the frame goes stale); the netapp's answers come back to that reply address as the
`frames` wire's text events. The broker client runs on an event loop of its own, in a thread, so `transmit` never
waits: the frame is handed to that loop. There is no INIT to wait for (the netapp opens the session on the first
frame) and no session state (frames may go to any replica that shares the queue).
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
import uuid
from concurrent.futures import Future
from typing import Any

from netapp.broker.address import parse_broker_url
from netapp.broker.channels import channel_for
from netapp.broker.frames import Envelope, expires_ns
from netapp.client.errors import ConnectionLost, NetAppError
from netapp.client.transports import SessionSettings, TransportCallbacks, report_error
from netapp.frame import EncodedFrame
from netapp.framing import ERROR_EVENT, pack_frame, read_event
from netapp.protocol import RESULTS_EVENT

log = logging.getLogger(__name__)


class BrokerTransport:
    """One robot session through a broker."""

    # A dropped broker connection is tried again within 1 s (the link's default doubles to 5 s): a broker that
    # restarted answers as soon as it listens, and refusing a connection costs it nothing.
    reconnect_max_s = 1.0

    def __init__(self, url: str, settings: SessionSettings, callbacks: TransportCallbacks) -> None:
        self.url = url
        self.settings = settings
        self.callbacks = callbacks
        self.address = parse_broker_url(url)  # ValueError for a wrong URL, before anything connects
        self._session = uuid.uuid4().hex
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True, name="netapp-broker")
        self._channel = channel_for(self.address)
        self._reply: str | None = None
        self._ready = False
        self._closed = False
        self._generation = 0  # which connection is the current one (each `_open` makes a new one)
        self._watching: asyncio.Task | None = None

    @property
    def session_id(self) -> str | None:
        return self._session if self._ready else None

    def connect(self) -> None:
        if not self._thread.is_alive():
            self._thread.start()
        try:
            self._reply = self._run(self._open(), self.settings.connect_timeout_s)
        except Exception as exc:  # noqa: BLE001 (whatever the client library raised: the broker cannot be reached)
            raise NetAppError(f"cannot reach the broker {self.address.redacted()}: {exc}") from exc
        if self.callbacks.state_to_restore() is not None:
            self.callbacks.on_restored(False, "a session through a broker keeps no state (any replica may answer)")
        self._ready = True
        self.callbacks.on_ready()

    async def _open(self) -> str:
        self._generation += 1
        generation = self._generation
        if generation > 1:  # a connection again after a loss: the lost one's client let go first
            await self._channel.close()
        await self._channel.connect()
        reply = await self._channel.open_replies(self._session, self._on_reply)
        self._watching = self._loop.create_task(self._watch(generation))
        return reply

    async def _watch(self, generation: int) -> None:
        """Tell the link at once when this connection is lost (a broker restarted), so it connects again then,
        rather than at the first frame that cannot be sent (a window full of frames waiting for results sends
        none)."""
        await self._channel.wait_closed()
        if generation != self._generation or self._closed or not self._ready:
            return  # a newer connection's, or closed on purpose, or already told by a failed send
        log.warning("broker %s: lost the connection", self.address.redacted())
        self._ready = False
        self.callbacks.on_lost()

    def transmit(self, frame: EncodedFrame) -> None:
        if not self._ready:
            raise ConnectionLost("the broker connection is down")
        envelope = Envelope(
            self.settings.robot_id or self._session,
            self._session,
            self._reply,
            expires_ns(frame.deadline_ms, time.time_ns()),
        )
        body = pack_frame(frame)
        sent = asyncio.run_coroutine_threadsafe(
            self._channel.send(body, envelope, str(frame.timestamp), frame.deadline_ms), self._loop
        )
        sent.add_done_callback(self._sent)

    def _sent(self, sent: Future) -> None:
        if sent.cancelled() or sent.exception() is None or self._closed:
            return
        log.warning("broker %s: a frame could not be sent (%s)", self.address.redacted(), sent.exception())
        if self._ready:
            self._ready = False
            self.callbacks.on_lost()

    async def _on_reply(self, body: bytes) -> None:
        try:
            found = read_event(body.decode())
        except UnicodeDecodeError:
            found = None
        if found is None or self._closed:
            return
        name, message = found
        if name == RESULTS_EVENT and isinstance(message.get("data"), dict):
            self.callbacks.on_result(message["data"])
        elif name == ERROR_EVENT:
            report_error(self.callbacks, message.get("data"))

    def _run(self, work: Any, timeout_s: float) -> Any:
        return asyncio.run_coroutine_threadsafe(work, self._loop).result(timeout_s)

    async def _close(self) -> None:
        if self._watching is not None:
            self._watching.cancel()
        await self._channel.close()

    def close(self) -> None:
        self._closed, self._ready = True, False
        if self._thread.is_alive():
            try:
                self._run(self._close(), 5.0)
            except Exception:  # noqa: BLE001 (closing a connection that is gone)
                pass
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(5)
