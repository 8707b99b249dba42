"""What a reader of a broker sees: subscribe first, then collect what arrives (the tests' and benches' end of the
broker channel). Each reader uses the same client library as the netapp's link."""

from __future__ import annotations

import asyncio
import time
import uuid
from collections.abc import Callable

import aio_pika
import aiomqtt
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties


class MqttReader:
    """Subscribed to `topic` (wildcards allowed); `messages` collects (topic, payload, retained). `session`: a
    client id whose session the broker keeps (MQTT 5 session expiry), so what is published while it is away waits
    for it (on a `Mosquitto(persistent=True)`, across restarts too)."""

    def __init__(self, host: str, port: int, topic: str, session: str | None = None) -> None:
        self.host, self.port, self.topic, self.session = host, port, topic, session
        self.messages: list[tuple[str, bytes, bool]] = []
        self._task: asyncio.Task | None = None
        self._ready = asyncio.Event()

    async def __aenter__(self) -> MqttReader:
        self._task = asyncio.create_task(self._read())
        await asyncio.wait_for(self._ready.wait(), 10)
        return self

    def _client(self) -> aiomqtt.Client:
        if self.session is None:
            return aiomqtt.Client(self.host, self.port, protocol=aiomqtt.ProtocolVersion.V5)
        properties = Properties(PacketTypes.CONNECT)
        properties.SessionExpiryInterval = 3600
        return aiomqtt.Client(
            self.host,
            self.port,
            identifier=self.session,
            protocol=aiomqtt.ProtocolVersion.V5,
            clean_start=False,
            properties=properties,
        )

    async def _read(self) -> None:
        async with self._client() as client:
            await client.subscribe(self.topic, qos=1)
            self._ready.set()
            async for message in client.messages:
                self.messages.append((str(message.topic), bytes(message.payload), bool(message.retain)))

    async def __aexit__(self, *exc: object) -> None:
        if self._task is not None:
            self._task.cancel()
            try:
                await self._task
            except (asyncio.CancelledError, aiomqtt.MqttError):
                pass


async def amqp_queue(url: str, binding: str = "#", exchange: str = "netapp") -> str:
    """A queue of its own bound to the durable topic `exchange`, kept when its connection closes (a connection
    killed by the test does not lose it); its name."""
    name = f"reader-{uuid.uuid4().hex[:8]}"
    async with await aio_pika.connect(url) as connection:
        channel = await connection.channel()
        topic = await channel.declare_exchange(exchange, aio_pika.ExchangeType.TOPIC, durable=True)
        queue = await channel.declare_queue(name, auto_delete=False)
        await queue.bind(topic, binding)
    return name


async def amqp_fetch(url: str, queue: str, count: int, timeout_s: float = 10.0) -> list[tuple[str, bytes]]:
    """Up to `count` (routing key, body) from `queue`, waiting up to `timeout_s` for them."""
    found: list[tuple[str, bytes]] = []
    deadline = time.monotonic() + timeout_s
    async with await aio_pika.connect(url) as connection:
        channel = await connection.channel()
        source = await channel.get_queue(queue, ensure=False)
        while len(found) < count and time.monotonic() < deadline:
            message = await source.get(fail=False)
            if message is None:
                await asyncio.sleep(0.02)  # polling the queue with a deadline
                continue
            await message.ack()
            found.append((message.routing_key or "", message.body))
    return found


def kafka_messages(bootstrap: str, topic: str, count: int, timeout_s: float = 20.0) -> list[tuple[bytes, bytes]]:
    """The first `count` (key, value) pairs of `topic`, read from the start (blocking: run it in a thread)."""
    from confluent_kafka import Consumer

    consumer = Consumer(
        {"bootstrap.servers": bootstrap, "group.id": f"reader-{time.monotonic_ns()}", "auto.offset.reset": "earliest"}
    )
    consumer.subscribe([topic])
    found: list[tuple[bytes, bytes]] = []
    deadline = time.monotonic() + timeout_s
    try:
        while len(found) < count and time.monotonic() < deadline:
            message = consumer.poll(0.5)
            if message is not None and message.error() is None:
                found.append((message.key(), message.value()))
    finally:
        consumer.close()
    return found


def kafka_committed(bootstrap: str, group: str, topic: str) -> int:
    """How many of `topic`'s messages `group` has committed, over all its partitions (a topic that started empty;
    blocking: run it in a thread)."""
    from confluent_kafka import Consumer, TopicPartition

    consumer = Consumer({"bootstrap.servers": bootstrap, "group.id": group})
    try:
        partitions = consumer.list_topics(topic, timeout=10).topics[topic].partitions
        found = consumer.committed([TopicPartition(topic, p) for p in partitions], timeout=10)
        return sum(max(0, tp.offset) for tp in found)
    finally:
        consumer.close()


def echoing(netapp) -> Callable:
    """A netapp end's handler that answers each frame with a `results` event naming its timestamp and robot."""
    from netapp.framing import event, parse_frame

    async def answer(incoming) -> None:
        frame = parse_frame(incoming.body)
        text = event("results", data={"timestamp": frame.timestamp, "robot": incoming.envelope.robot})
        await netapp.reply(incoming.envelope, incoming.correlation, text.encode())
        await incoming.ack()

    return answer


async def wait_until(check: Callable[[], bool], timeout_s: float = 10.0) -> bool:
    """Until `check()` holds (polled every 20 ms) or `timeout_s` passes; whether it held."""
    deadline = time.monotonic() + timeout_s
    while not check():
        if time.monotonic() > deadline:
            return False
        await asyncio.sleep(0.02)
    return True
