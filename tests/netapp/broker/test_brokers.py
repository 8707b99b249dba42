"""The test brokers themselves (tests/support/brokers.py): each is up, on loopback, and carries a message."""

from __future__ import annotations

import asyncio

import pytest

pytest.importorskip("aio_pika")
pytest.importorskip("aiomqtt")

import aio_pika  # noqa: E402
import aiomqtt  # noqa: E402

from tests.support.broker_readers import MqttReader, kafka_messages, wait_until  # noqa: E402


async def test_rabbitmq_runs_as_its_own_user_on_loopback_and_carries_a_message(rabbitmq):
    assert rabbitmq.environment()["RABBITMQ_MNESIA_BASE"].startswith("/tmp")  # its state in a temporary folder
    connection = await aio_pika.connect(rabbitmq.url)
    async with connection:
        channel = await connection.channel(publisher_confirms=True)
        queue = await channel.declare_queue(exclusive=True)
        await channel.default_exchange.publish(aio_pika.Message(b"hello"), routing_key=queue.name)
        message = await queue.get(timeout=5)
        assert message.body == b"hello"
        await message.ack()
    users = rabbitmq.ctl("list_connections", "user")  # the node answers its own control tool
    assert "Listing connections" in users


async def test_mosquitto_carries_a_message_and_comes_back_after_a_restart(mosquitto):
    async with MqttReader("127.0.0.1", mosquitto.port, "fixture/#") as reader:
        async with aiomqtt.Client("127.0.0.1", mosquitto.port) as client:
            await client.publish("fixture/one", b"hello", qos=1)
        assert await wait_until(lambda: reader.messages)
    assert reader.messages[0][:2] == ("fixture/one", b"hello")
    await asyncio.to_thread(mosquitto.restart)  # same port: what the outage tests do
    async with aiomqtt.Client("127.0.0.1", mosquitto.port) as client:
        await client.publish("fixture/two", b"again", qos=1)


def test_kafka_mock_or_real_kafka_carries_a_keyed_message(kafka_url):
    """librdkafka's mock cluster (a test double, not Kafka) unless KAFKA_BOOTSTRAP names a real broker."""
    from confluent_kafka import Producer

    bootstrap = kafka_url.removeprefix("kafka://").rstrip("/")
    producer = Producer({"bootstrap.servers": bootstrap, "acks": "all", "enable.idempotence": True})
    producer.produce("fixture", b"hello", key=b"k")
    assert producer.flush(10) == 0
    assert kafka_messages(bootstrap, "fixture", 1) == [(b"k", b"hello")]
