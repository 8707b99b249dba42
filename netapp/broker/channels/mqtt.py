"""Frames through MQTT 5: the netapp's replicas share the topic `netapp/<netapp>/frames` through one shared
subscription (`$share/<netapp>/...`), so the broker spreads the frames over them; each holds at most `prefetch=`
unacknowledged (its Receive Maximum, with the acknowledgement sent once the frame is answered). A frame carries its
deadline as the message expiry interval (whole seconds: the broker drops it once stale) and as `expires_ns`, its
robot in user properties, and its reply address as the response topic with correlation data. A frame that cannot be
decoded is acknowledged and counted (MQTT has no dead letters): never redelivered."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Awaitable, Callable

import aiomqtt
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from netapp.broker.address import BrokerAddress
from netapp.broker.channel import Incoming
from netapp.broker.frames import Envelope, expiry_s, read_envelope
from netapp.broker.link import CONNECT_TIMEOUT_S
from netapp.broker.links.mqtt import CLIENT_LOG, enter
from netapp.framing import WireError

QOS = 1


class MqttFrames:
    spreads_robots = True  # Mosquitto deals a shared subscription's messages round robin

    def __init__(self, address: BrokerAddress) -> None:
        self.address = address
        self.topic = address.fill("frames", "")
        self._client: aiomqtt.Client | None = None
        self._reader: asyncio.Task | None = None
        self._handlers: list[tuple[str, Callable[[aiomqtt.Message], Awaitable[None]]]] = []

    async def connect(self) -> None:
        self._handlers = []  # a connection again (the robot's, after a loss) subscribes again
        properties = Properties(PacketTypes.CONNECT)
        properties.ReceiveMaximum = self.address.prefetch  # the broker sends no more unacknowledged: the prefetch
        (host, port) = self.address.hosts[0]
        client = aiomqtt.Client(
            host,
            port,
            username=self.address.username,
            password=self.address.password,
            protocol=aiomqtt.ProtocolVersion.V5,
            properties=properties,
            timeout=CONNECT_TIMEOUT_S,
            logger=CLIENT_LOG,
        )
        await enter(client)
        client._client.manual_ack_set(True)  # paho's own switch, which aiomqtt does not wrap: ack once answered
        self._client = client
        self._reader = asyncio.get_running_loop().create_task(self._read())

    async def _read(self) -> None:
        async for message in self._client.messages:
            for pattern, handler in self._handlers:
                if message.topic.matches(pattern):
                    await handler(message)
                    break
            else:
                self._ack(message)

    def _ack(self, message: aiomqtt.Message) -> None:
        if message.qos > 0:
            self._client._client.ack(message.mid, message.qos)

    async def _settle(self, message: aiomqtt.Message) -> None:
        self._ack(message)

    async def consume(self, handler: Callable[[Incoming], Awaitable[None]]) -> None:
        async def take(message: aiomqtt.Message) -> None:
            properties = message.properties
            user = dict(getattr(properties, "UserProperty", []) or [])
            reply = getattr(properties, "ResponseTopic", None)
            correlation = getattr(properties, "CorrelationData", None)
            try:
                envelope, problem = read_envelope(user, reply), None
            except WireError as exc:
                envelope, problem = None, str(exc)
            settle = lambda: self._settle(message)  # noqa: E731 (the same for both: MQTT has no dead letters)
            body = message.payload if isinstance(message.payload, bytes) else bytes(message.payload or b"")
            await handler(
                Incoming(body, envelope, problem, correlation.decode() if correlation else None, settle, settle)
            )

        # the shared subscription's group is the netapp: its replicas share the frames, another netapp has its own
        self._handlers.append((self.topic, take))
        await self._client.subscribe(f"$share/{self.address.netapp}/{self.topic}", qos=QOS)

    async def reply(self, envelope: Envelope, correlation: str | None, body: bytes) -> None:
        properties = Properties(PacketTypes.PUBLISH)
        if correlation:
            properties.CorrelationData = correlation.encode()
        await self._client.publish(envelope.reply, body, qos=QOS, properties=properties)

    async def open_replies(self, session: str, handler: Callable[[bytes], Awaitable[None]]) -> str:
        topic = self.address.fill("replies", session)

        async def take(message: aiomqtt.Message) -> None:
            self._ack(message)
            await handler(bytes(message.payload or b""))

        self._handlers.append((topic, take))
        await self._client.subscribe(topic, qos=QOS)
        return topic

    async def send(self, body: bytes, envelope: Envelope, correlation: str, deadline_ms: float | None) -> None:
        properties = Properties(PacketTypes.PUBLISH)
        properties.UserProperty = list(envelope.headers().items())
        properties.CorrelationData = correlation.encode()
        if envelope.reply:
            properties.ResponseTopic = envelope.reply
        expiry = expiry_s(deadline_ms)
        if expiry is not None:
            properties.MessageExpiryInterval = expiry
        await self._client.publish(self.topic, body, qos=QOS, properties=properties)

    async def wait_closed(self) -> None:
        reader = self._reader
        if reader is not None:
            with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
                await asyncio.shield(reader)  # its reading ends when the connection does

    async def close(self) -> None:
        client, self._client = self._client, None
        if self._reader is not None:
            self._reader.cancel()
            with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
                await self._reader
        if client is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(client.__aexit__(None, None, None), CONNECT_TIMEOUT_S)
