"""The publisher (netapp/broker/publisher.py) against real brokers: at least once on each (RabbitMQ with publisher
confirms, Mosquitto with QoS 1, Kafka with acks=all and idempotence: librdkafka's mock cluster, not Kafka, unless
KAFKA_BOOTSTRAP is set), in order per source; a broker down at start-up or lost mid-stream delays nothing, the
backlog is kept and sent once it is back, each told in one log line; overflow counted by reason and said once."""

from __future__ import annotations

import asyncio
import logging
import time

import pytest

pytest.importorskip("aio_pika")
pytest.importorskip("aiomqtt")
pytest.importorskip("confluent_kafka")

from netapp.broker.address import parse_broker_url  # noqa: E402
from netapp.broker.publisher import Publisher, PublisherEvents  # noqa: E402
from tests.support.broker_readers import (  # noqa: E402
    MqttReader,
    amqp_fetch,
    amqp_queue,
    kafka_messages,
    wait_until,
)
from tests.support.brokers import Mosquitto  # noqa: E402

LOGGER = "netapp.broker.publisher"


def offer_numbered(publisher: Publisher, count: int, start: int = 0) -> None:
    for n in range(start, start + count):
        topic, key = publisher.address.destination("robot-1")
        publisher.offer(topic, str(n).encode(), key=key)


async def test_rabbitmq_gets_every_result_in_order_with_confirms(rabbitmq):
    queue = await amqp_queue(rabbitmq.url, "results.edge.*")
    publisher = Publisher(parse_broker_url(rabbitmq.url, "edge"))
    publisher.start()
    offer_numbered(publisher, 300)  # more than one batch
    assert await wait_until(lambda: publisher.published == 300)
    await publisher.close()
    got = await amqp_fetch(rabbitmq.url, queue, 300)
    assert [body for _, body in got] == [str(n).encode() for n in range(300)]
    assert {key for key, _ in got} == {"results.edge.robot-1"}


async def test_mosquitto_gets_every_result_in_order_and_the_available_topic(mosquitto):
    url = f"mqtt://127.0.0.1:{mosquitto.port}"
    async with MqttReader("127.0.0.1", mosquitto.port, "netapp/edge/#") as reader:
        publisher = Publisher(parse_broker_url(url, "edge"))
        publisher.start()
        offer_numbered(publisher, 50)
        assert await wait_until(lambda: len([m for m in reader.messages if m[0].endswith("/results")]) == 50)
        await publisher.close()
        assert await wait_until(lambda: reader.messages[-1][1] == b"offline")
    results = [body for topic, body, _ in reader.messages if topic == "netapp/edge/robot-1/results"]
    assert results == [str(n).encode() for n in range(50)]
    available = [body for topic, body, _ in reader.messages if topic == "netapp/edge/available"]
    assert available[0] == b"online" and available[-1] == b"offline"


async def test_a_late_reader_learns_availability_from_the_retained_message(mosquitto):
    url = f"mqtt://127.0.0.1:{mosquitto.port}"
    publisher = Publisher(parse_broker_url(url, "late"))
    publisher.start()
    assert await wait_until(lambda: publisher.connected)
    async with MqttReader("127.0.0.1", mosquitto.port, "netapp/late/available") as reader:
        assert await wait_until(lambda: reader.messages)
    assert reader.messages[0] == ("netapp/late/available", b"online", True)
    await publisher.close()


async def test_kafka_gets_every_result_keyed_by_netapp_and_source(kafka_url):
    """librdkafka's mock cluster (a test double of Kafka) unless KAFKA_BOOTSTRAP names a real broker."""
    address = parse_broker_url(kafka_url + "?topic=results-test", "edge")
    publisher = Publisher(address)
    publisher.start()
    offer_numbered(publisher, 100)
    assert await wait_until(lambda: publisher.published == 100, 20)
    await publisher.close()
    bootstrap = ",".join(f"{h}:{p}" for h, p in address.hosts)
    got = await asyncio.to_thread(kafka_messages, bootstrap, "results-test", 100)
    assert [value for _, value in got] == [str(n).encode() for n in range(100)]
    assert {key for key, _ in got} == {b"edge/robot-1"}


async def test_down_at_start_then_lost_mid_stream_delays_nothing_and_loses_nothing(caplog):
    """Mosquitto with persistence and a reader whose session it keeps: what the publisher buffered while the broker
    was away reaches the reader once both are back."""
    caplog.set_level(logging.INFO, LOGGER)
    broker = Mosquitto(persistent=True)
    try:
        broker.start()
        async with MqttReader("127.0.0.1", broker.port, "netapp/edge/+/results", session="lake"):
            pass  # the reader's session now exists; it is offline from here on, its messages kept for it
        await asyncio.to_thread(broker.down)
        events: list[bool] = []
        publisher = Publisher(
            parse_broker_url(f"mqtt://127.0.0.1:{broker.port}", "edge"), events=PublisherEvents(connected=events.append)
        )
        publisher.start()
        began = time.perf_counter()
        offer_numbered(publisher, 20)
        assert time.perf_counter() - began < 0.05  # offering never waits on the broker
        await asyncio.sleep(0.5)
        assert not publisher.connected and len(publisher.backlog) == 20
        await asyncio.to_thread(broker.start)
        assert await wait_until(lambda: publisher.published == 20, 10)
        await asyncio.to_thread(broker.restart)  # lost mid-stream: these wait, and go once it is back
        offer_numbered(publisher, 20, start=20)
        assert await wait_until(lambda: publisher.published == 40, 10)
        await publisher.close()
        async with MqttReader("127.0.0.1", broker.port, "netapp/edge/+/results", session="lake") as reader:
            assert await wait_until(lambda: len({body for _, body, _ in reader.messages}) == 40, 10)
        assert {body for _, body, _ in reader.messages} == {str(n).encode() for n in range(40)}
    finally:
        broker.stop()
    lines = [r.getMessage() for r in caplog.records if r.name == LOGGER]
    name = f"broker mqtt://127.0.0.1:{broker.port}/"
    assert sum(line.startswith(f"{name}: unreachable") for line in lines) == 1
    assert sum(line.startswith(f"{name}: connected after") for line in lines) == 1
    assert sum(line.startswith(f"{name}: lost") for line in lines) == 1
    assert sum(line.startswith(f"{name}: back after") for line in lines) == 1
    assert events[0] is True and False in events  # what the metrics hear


async def test_rabbitmq_connections_killed_mid_stream_are_opened_again_with_nothing_lost(rabbitmq):
    queue = await amqp_queue(rabbitmq.url, "results.killed.*")
    publisher = Publisher(parse_broker_url(rabbitmq.url, "killed"))
    publisher.start()
    offer_numbered(publisher, 50)
    assert await wait_until(lambda: publisher.published == 50)
    await asyncio.to_thread(rabbitmq.ctl, "close_all_connections", "test: the broker goes away")
    offer_numbered(publisher, 50, start=50)
    assert await wait_until(lambda: publisher.published == 100, 15)
    await publisher.close()
    got = {body for _, body in await amqp_fetch(rabbitmq.url, queue, 100)}
    assert got == {str(n).encode() for n in range(100)}  # at least once: each arrived


class NeverThere:
    """A link to a broker that never answers (the publisher's own bounds, without a broker)."""

    def __init__(self, address) -> None:
        pass

    async def connect(self) -> None:
        raise ConnectionRefusedError("refused")

    async def publish(self, batch) -> None:
        raise AssertionError("never connected")

    async def close(self) -> None:
        pass


async def test_overflow_is_bounded_counted_by_reason_and_said_once(caplog):
    caplog.set_level(logging.INFO, LOGGER)
    dropped: list[str] = []
    address = parse_broker_url("mqtt://nowhere?buffer=10&buffer_mb=0.001", "n")  # 10 results, 1048 bytes
    publisher = Publisher(address, link=NeverThere, events=PublisherEvents(dropped=dropped.append))
    publisher.start()
    for _ in range(30):
        publisher.offer("t", b"x" * 50)
    assert dropped == ["count"] * 20
    publisher.offer("t", b"y" * 2000)
    assert dropped[-1] == "too_large"
    for _ in range(3):
        publisher.offer("t", b"z" * 400)
        assert len(publisher.backlog) <= 10 and publisher.backlog.bytes <= 1048
    assert dropped.count("bytes") >= 1
    await asyncio.sleep(0.3)
    await publisher.close(flush_s=0)
    said = [r for r in caplog.records if "buffer is full" in r.getMessage()]
    assert len(said) == 1 and "dropping the oldest" in said[0].getMessage()
