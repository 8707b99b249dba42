"""Frames through RabbitMQ: the durable queue `netapp.frames.<netapp>` that every replica of the netapp consumes with
a bounded prefetch (RabbitMQ spreads the frames over them), each frame with its deadline as the message's own
expiration (RabbitMQ drops it in the queue once stale), a `reply_to` queue of the robot's own and a
`correlation_id`. A frame that cannot be decoded is dead-lettered by the netapp itself (published to the direct
exchange `netapp.dead` with its netapp's name, whose queue `netapp.dead.<netapp>` keeps the last 1000 for a look,
then acknowledged: never
redelivered); the frames queue has no dead-letter exchange of its own, so what RabbitMQ drops as stale is not kept.

aio-pika opens the connection, declares and watches; each frame's own work (publish, delivery, acknowledgement) goes
through its underlying aiormq channel, without aio-pika's message objects: on this 2-core VM, Python's work per message
costs three times as much 40 ms after the last message as back to back, and aiormq alone does a quarter less of it
(docs/benchmarks.md#frames-through-a-broker-against-frames-issue-41)."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable

import aio_pika
import aiormq
from pamqp.commands import Basic

from netapp.broker.address import BrokerAddress
from netapp.broker.channel import Incoming
from netapp.broker.frames import Envelope, read_envelope
from netapp.broker.links.amqp import open_connection
from netapp.broker.message import CONTENT_TYPE
from netapp.framing import WireError

DEAD_LETTERS_KEPT = 1000


class AmqpFrames:
    spreads_robots = True  # a waiting frame goes to whichever replica is free

    def __init__(self, address: BrokerAddress) -> None:
        self.address = address
        self.queue_name = address.fill("frames", "")
        self._connection: aio_pika.abc.AbstractConnection | None = None
        self._channel: aio_pika.abc.AbstractChannel | None = None
        self._frames: aiormq.abc.AbstractChannel | None = None  # the channel's aiormq side: each frame's own work
        self._lost = asyncio.Event()  # set once the connection is gone, whoever closed it

    async def connect(self) -> None:
        """Declare the dead-letter exchange and its queue, then the frames queue (robot and netapp alike: the same
        arguments, so either may come first)."""
        self._connection = await open_connection(self.address)
        lost = self._lost = asyncio.Event()
        # aio-pika calls these whether the broker or we closed it (its `is_closed` says only the latter)
        self._connection.close_callbacks.add(lambda *_: lost.set())
        channel = self._channel = await self._connection.channel(publisher_confirms=False)
        await channel.set_qos(prefetch_count=self.address.prefetch)
        self._dead = self.address.fill("dead_letter", "")
        # direct, by netapp: each netapp's dead letters in its own queue
        dead = await channel.declare_exchange(self._dead, aio_pika.ExchangeType.DIRECT, durable=True)
        kept = await channel.declare_queue(
            f"{self._dead}.{self.address.netapp}", durable=True, arguments={"x-max-length": DEAD_LETTERS_KEPT}
        )
        await kept.bind(dead, routing_key=self.address.netapp)
        await channel.declare_queue(self.queue_name, durable=True)
        self._frames = await channel.get_underlay_channel()

    async def consume(self, handler: Callable[[Incoming], Awaitable[None]]) -> None:
        frames = self._frames

        async def take(message: aiormq.abc.DeliveredMessage) -> None:
            properties, tag = message.header.properties, message.delivery.delivery_tag
            try:
                envelope, problem = read_envelope(properties.headers, properties.reply_to), None
            except WireError as exc:
                envelope, problem = None, str(exc)
            await handler(
                Incoming(
                    message.body,
                    envelope,
                    problem,
                    properties.correlation_id,
                    ack=lambda: frames.basic_ack(tag, wait=False),
                    reject=lambda: self._dead_letter(message),
                )
            )

        await frames.basic_consume(self.queue_name, take)

    async def _dead_letter(self, message: aiormq.abc.DeliveredMessage) -> None:
        properties = Basic.Properties(headers=message.header.properties.headers)
        await self._frames.basic_publish(
            message.body, exchange=self._dead, routing_key=self.address.netapp, properties=properties
        )
        await self._frames.basic_ack(message.delivery.delivery_tag, wait=False)

    async def reply(self, envelope: Envelope, correlation: str | None, body: bytes) -> None:
        # mandatory=False: a robot that is gone (its queue with it) is not an error of the netapp's
        properties = Basic.Properties(content_type=CONTENT_TYPE, correlation_id=correlation, message_id=correlation)
        await self._frames.basic_publish(body, routing_key=envelope.reply, properties=properties, wait=False)

    async def open_replies(self, session: str, handler: Callable[[bytes], Awaitable[None]]) -> str:
        queue = await self._channel.declare_queue(exclusive=True)  # the server names it; gone with the connection

        async def take(message: aiormq.abc.DeliveredMessage) -> None:
            await handler(message.body)

        await self._frames.basic_consume(queue.name, take, no_ack=True)
        return queue.name

    async def send(self, body: bytes, envelope: Envelope, correlation: str, deadline_ms: float | None) -> None:
        properties = Basic.Properties(
            reply_to=envelope.reply,
            correlation_id=correlation,
            message_id=correlation,  # else aiormq makes a random one for each message
            expiration=str(max(1, round(deadline_ms))) if deadline_ms else None,  # ms, as AMQP's text
            headers=envelope.headers(),
        )
        # waits until written: a robot that closes right after its last frame must not leave it in the write queue
        await self._frames.basic_publish(body, routing_key=self.queue_name, properties=properties)

    async def wait_closed(self) -> None:
        if self._connection is not None:
            await self._lost.wait()

    async def close(self) -> None:
        connection, self._connection = self._connection, None
        if connection is not None:
            try:
                await connection.close()
            except Exception:  # noqa: BLE001 (a connection already gone closes with whatever error)
                pass
