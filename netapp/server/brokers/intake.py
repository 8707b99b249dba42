"""`netapp serve --consume URL`: frames from a broker's work queue, one more transport of the netapp
(docs/broker.md#frames-through-a-broker).

Each robot (its `session` header) is one `Connection` (`netapp.server.connection`), opened by the one command
dispatch with an INIT of its own on its first frame (`robot_id` from its headers) and closed when it has been idle
for the session TTL; its wire part is its reply address (`BrokerWire`). Each message is the `frames` wire's binary
frame (`netapp.framing.parse_frame`: the one `EncodedFrame`), taken as the `frames` endpoint takes one, through
`DataPlane.submit` (newest wins per robot, admission, priorities and fair share as everywhere). This intake is the
result sink of its frames: each result or error goes back to the robot's reply address as the `frames` wire's text
event, and only then is the message acknowledged. What is not answered: a stale frame (past its `expires_ns`:
acknowledged and counted, `reason="stale"`); a message over the size limit or that cannot be parsed (dead-lettered
on RabbitMQ, acknowledged on MQTT; counted, never redelivered).
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from netapp.backoff import Outage, backoff_s
from netapp.broker.address import BrokerAddress
from netapp.broker.channel import FrameChannel, Incoming
from netapp.broker.channels import channel_for
from netapp.broker.frames import Envelope
from netapp.framing import ERROR_EVENT, HEADER, MAX_META_BYTES, WireError, event, parse_frame
from netapp.protocol import RESULTS_EVENT, CommandType, error_event
from netapp.server.commands import Commands
from netapp.server.connection import Connection
from netapp.server.dataplane import DataPlane, IncomingFrame
from netapp.server.decoding.h264 import H264Decoder
from netapp.server.errors import FrameError, FrameRejected
from netapp.server.frames.decoding import FrameDecoding
from netapp.server.sessions import Session
from netapp.server.settings import Settings

log = logging.getLogger(__name__)

# A lost work queue is tried again at most 1 s apart (0.5 to 1 s at the cap, with jitter), so that a broker that is
# back gets its first frame answered within 2 s of its return (the robot tries as often: `BrokerTransport`).
RETRY_CAP_S = 1.0


@dataclass
class BrokerWire:
    """A broker robot's own part of its connection: where its answers go, and its messages not yet answered (by
    frame timestamp: a result or error names its frame by it)."""

    envelope: Envelope
    unanswered: dict[int, Incoming] = field(default_factory=dict)
    last_s: float = field(default_factory=time.monotonic)


class BrokerIntake:
    """One `--consume` broker: its channel, its robots' connections, and the result sink of their frames."""

    def __init__(
        self,
        address: BrokerAddress,
        dataplane: DataPlane,
        settings: Settings,
        commands: Commands,
        h264: H264Decoder,
        channel: Callable[[BrokerAddress], FrameChannel] = channel_for,
    ) -> None:
        self.address = address
        self.label = f"broker-{address.kind}"  # the transport label of its sessions and metrics
        self.dataplane = dataplane
        self.settings = settings
        self.commands = commands
        self.decoding = FrameDecoding(settings, h264)
        self.outage = Outage(address.redacted(), kind="broker", cap_s=RETRY_CAP_S)
        self.max_message = settings.max_payload_bytes + HEADER.size + MAX_META_BYTES
        self._make_channel = channel
        self._channel: FrameChannel | None = None
        self._task: asyncio.Task | None = None

    def start(self) -> None:
        self._task = asyncio.get_running_loop().create_task(self.run(), name=f"consume {self.address.redacted()}")

    async def run(self) -> None:
        """Connect and consume; a lost broker is connected again with backoff, one log line each way."""
        while True:
            channel = self._make_channel(self.address)
            try:
                await channel.connect()
                # before consuming: a frame may be handled before `consume` returns, and is answered through it
                self._channel = channel
                await channel.consume(self.on_message)
            except Exception as exc:  # noqa: BLE001 (any failure to connect is an outage, said once)
                self._channel = None
                await channel.close()
                line = self.outage.failed(time.monotonic(), type(exc).__name__)
                if line:
                    log.warning("%s; frames wait in the broker meanwhile", line)
                await asyncio.sleep(backoff_s(self.outage.attempts - 1, 0.1, RETRY_CAP_S))
                continue
            line = self.outage.connected(time.monotonic())
            if line:
                log.info("%s: consuming %s", line, self.address.fill("frames", ""))
            await self._watch(channel)
            self._channel = None
            await channel.close()

    async def _watch(self, channel: FrameChannel) -> None:
        """Until the channel is lost: close robots idle for the session TTL on the way."""
        period = max(1.0, self.settings.session_ttl_s / 4)
        waiting = asyncio.ensure_future(channel.wait_closed())
        try:
            while not waiting.done():
                await asyncio.wait([waiting], timeout=period)
                self.expire_idle()
        finally:
            waiting.cancel()
        self.outage.failed(time.monotonic(), "the connection was lost")
        log.warning("broker %s: lost; frames wait in the broker meanwhile", self.address.redacted())

    def expire_idle(self) -> None:
        ttl = self.settings.session_ttl_s
        for connection in self.dataplane.connections(self.label):
            if time.monotonic() - connection.wire.last_s > ttl:
                self.dataplane.disconnect(connection, "no frame for the session TTL")

    async def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
        for connection in self.dataplane.connections(self.label):
            self.dataplane.disconnect(connection, "the netapp stops")
        if self._channel is not None:
            await self._channel.close()

    # -- frames ---------------------------------------------------------------------------------------------------

    async def on_message(self, incoming: Incoming) -> None:
        recv_ns = time.monotonic_ns()
        envelope = incoming.envelope
        if envelope is None:  # not a robot's: nobody to answer
            self.dataplane.refuse(self.label, "bad_envelope")
            return await incoming.reject()
        if envelope.stale(time.time_ns()):  # a backlog an outage left: never answered late
            self.dataplane.refuse(self.label, "stale")
            return await incoming.ack()
        if len(incoming.body) > self.max_message:  # refused before anything is parsed or decoded
            limit = self.settings.max_payload_bytes
            return await self._poison(incoming, "payload_too_large", f"a frame over {limit} bytes")
        connection = await self._connection(envelope)
        if connection is None:
            return await incoming.ack()  # refused (told to the robot)
        wire: BrokerWire = connection.wire
        wire.last_s = time.monotonic()
        try:
            frame = parse_frame(incoming.body)  # the frames wire's edge
        except WireError as exc:
            return await self._poison(incoming, exc.reason, str(exc))
        earlier = wire.unanswered.pop(frame.timestamp, None)
        if earlier is not None:  # the same timestamp again: the earlier one is answered by this one's answer
            await earlier.ack()
        wire.unanswered[frame.timestamp] = incoming

        async def parse() -> IncomingFrame:
            return self.decoding.incoming(connection, frame)

        try:
            await self.dataplane.submit(connection.live_session, self.label, parse, recv_ns=recv_ns, sink=self)
        except FrameRejected as exc:  # counted by the dataplane
            wire.unanswered.pop(frame.timestamp, None)
            await self._answer(envelope, incoming, event(ERROR_EVENT, exc.event(frame.timestamp)))

    async def _poison(self, incoming: Incoming, reason: str, why: str) -> None:
        """A message that is not a frame: counted, the robot told, and dead-lettered (never redelivered)."""
        self.dataplane.refuse(self.label, reason)
        log.debug("broker frame refused (%s): %s", reason, why)
        if self._channel is not None:
            text = event(ERROR_EVENT, error_event(None, why, reason))
            await self._channel.reply(incoming.envelope, incoming.correlation, text.encode())
        await incoming.reject()

    async def _connection(self, envelope: Envelope) -> Connection | None:
        """The robot's connection, opened (with its INIT) on its first frame; None when its INIT was refused."""
        connection = self.dataplane.connection(envelope.session)
        if connection is not None and connection.live_session is not None:
            connection.wire.envelope = envelope  # its latest reply address
            return connection
        connection = Connection(envelope.session, self.label, self, BrokerWire(envelope), self.settings.robot_priority)
        self.dataplane.connect(connection)
        answer = await self.commands.execute(
            connection, {"cmd_type": int(CommandType.INIT), "data": {"robot_id": envelope.robot}}
        )
        if not answer.ok:
            self.dataplane.disconnect(connection, answer.message)
            text = event(ERROR_EVENT, error_event(None, answer.message, answer.refused.get("reason", "init_refused")))
            await self._channel.reply(envelope, None, text.encode())
            return None
        connection.session.frames_spread = self._channel.spreads_robots  # over the replicas on the queue, or not
        return connection

    async def _answer(self, envelope: Envelope, incoming: Incoming | None, text: str) -> None:
        channel = self._channel
        if channel is not None:
            try:
                await channel.reply(envelope, incoming.correlation if incoming else None, text.encode())
            except Exception:  # noqa: BLE001 (the broker went away: the frame comes again, or goes stale)
                log.debug("could not answer a broker robot", exc_info=True)
                return
        if incoming is not None:
            await incoming.ack()

    # -- the result sink ------------------------------------------------------------------------------------------

    async def result(self, session: Session, message: dict[str, Any]) -> None:
        await self._settle(session, message.get("timestamp"), event(RESULTS_EVENT, message))

    async def error(self, session: Session, timestamp: int | None, error: FrameError) -> None:
        await self._settle(session, timestamp, event(ERROR_EVENT, error.event(timestamp)))

    async def _settle(self, session: Session, timestamp: int | None, text: str) -> None:
        connection = self.dataplane.connection(session.id)
        if connection is None:
            return
        wire: BrokerWire = connection.wire
        await self._answer(wire.envelope, wire.unanswered.pop(timestamp, None), text)
