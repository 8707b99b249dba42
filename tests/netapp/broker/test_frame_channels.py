"""Frames through a broker, both ends of the channel (netapp/broker/channels/), against a real RabbitMQ and Mosquitto:
a robot's frame reaches the netapp's end with its envelope and comes back on the robot's own reply address; a stale
one is dropped by the broker; a poison one is dead-lettered (RabbitMQ), never redelivered; two consumers share the
work queue, each holding at most its prefetch."""

from __future__ import annotations

import asyncio
import socket
import time

import pytest

pytest.importorskip("aio_pika")
pytest.importorskip("aiomqtt")

from netapp.broker.address import parse_broker_url  # noqa: E402
from netapp.broker.channels.amqp import AmqpFrames  # noqa: E402
from netapp.broker.channels.mqtt import MqttFrames  # noqa: E402
from netapp.broker.frames import Envelope, expires_ns  # noqa: E402
from netapp.frame import JPEG, EncodedFrame  # noqa: E402
from netapp.framing import pack_frame  # noqa: E402
from tests.support.broker_readers import amqp_fetch, echoing, wait_until  # noqa: E402


async def opened(url: str, name: str, **options):
    query = "&".join(f"{k}={v}" for k, v in {"netapp": name, **options}.items())
    address = parse_broker_url(f"{url}?{query}")
    channel = AmqpFrames(address) if address.kind == "amqp" else MqttFrames(address)
    await channel.connect()
    return channel


@pytest.fixture(params=["amqp", "mqtt"])
def broker_url(request) -> str:
    if request.param == "amqp":
        return request.getfixturevalue("rabbitmq").url
    return f"mqtt://127.0.0.1:{request.getfixturevalue('mosquitto').port}/"


async def test_a_frame_goes_to_the_queue_and_its_answer_to_the_robots_own_address(broker_url):
    netapp, robot = await opened(broker_url, "echo"), await opened(broker_url, "echo")
    replies: list[bytes] = []

    async def keep(body: bytes) -> None:
        replies.append(body)

    reply_to = await robot.open_replies("session-1", keep)

    await netapp.consume(echoing(netapp))
    frame = EncodedFrame(JPEG, 123, b"\xff\xd8jpeg", deadline_ms=5000)
    envelope = Envelope("robot-1", "session-1", reply_to, expires_ns(5000, time.time_ns()))
    await robot.send(pack_frame(frame), envelope, "123", frame.deadline_ms)
    assert await wait_until(lambda: replies)
    assert b'"robot":"robot-1"' in replies[0] and b'"timestamp":123' in replies[0]
    await robot.close()
    await netapp.close()


async def test_a_stale_frame_is_dropped_by_the_broker_and_a_poison_one_dead_lettered(rabbitmq):
    robot = await opened(rabbitmq.url, "stale")
    frame = EncodedFrame(JPEG, 1, b"x", deadline_ms=50)
    await robot.send(pack_frame(frame), Envelope("r", "s", "nowhere"), "1", frame.deadline_ms)
    await robot.send(b"not a frame", Envelope("r", "s", "nowhere"), "2", None)
    await asyncio.sleep(0.2)  # the first one's 50 ms pass while no netapp consumes
    netapp = await opened(rabbitmq.url, "stale")
    seen: list[bytes] = []

    async def reject_poison(incoming) -> None:
        seen.append(incoming.body)
        await incoming.reject()

    await netapp.consume(reject_poison)
    assert await wait_until(lambda: seen)
    await asyncio.sleep(0.2)
    assert seen == [b"not a frame"]  # the stale frame never arrived, the poison one once
    await netapp.close()
    dead = await amqp_fetch(rabbitmq.url, "netapp.dead.stale", 1)
    assert [body for _, body in dead] == [b"not a frame"]
    await robot.close()


async def test_two_consumers_share_the_queue_each_within_its_prefetch(broker_url):
    robot = await opened(broker_url, "shared")
    held: dict[str, list] = {"a": [], "b": []}

    def holder(name: str):
        async def hold(incoming) -> None:
            held[name].append(incoming)  # never settled: what each holds is its prefetch at most

        return hold

    replicas = [await opened(broker_url, "shared", prefetch=3) for _ in range(2)]
    await replicas[0].consume(holder("a"))
    await replicas[1].consume(holder("b"))
    for n in range(10):
        await robot.send(pack_frame(EncodedFrame(JPEG, n, b"x")), Envelope("r", "s", "nowhere"), str(n), None)
    assert await wait_until(lambda: len(held["a"]) + len(held["b"]) == 6)
    await asyncio.sleep(0.2)
    assert len(held["a"]) == 3 and len(held["b"]) == 3  # the other 4 wait in the broker
    for incoming in held["a"]:
        await incoming.ack()
    # RabbitMQ gives the 4 waiting to whoever is free (3 to a); Mosquitto assigns a shared subscription's messages
    # when they are published, round robin, so a gets the 2 that were its own
    assert await wait_until(lambda: len(held["a"]) == (6 if broker_url.startswith("amqp") else 5))
    for replica in replicas:
        await replica.close()
    await robot.close()


async def test_headers_that_are_not_a_robots_are_a_problem_not_a_crash(rabbitmq):
    import aio_pika

    netapp = await opened(rabbitmq.url, "hostile")
    seen = []

    async def keep(incoming) -> None:
        seen.append(incoming)
        await incoming.reject()

    await netapp.consume(keep)
    async with await aio_pika.connect(rabbitmq.url) as connection:
        channel = await connection.channel()
        await channel.default_exchange.publish(
            aio_pika.Message(b"x", headers={"robot_id": "r" * 1000}), routing_key="netapp.frames.hostile"
        )
    assert await wait_until(lambda: seen)
    assert seen[0].envelope is None and "at most 128" in seen[0].problem
    await netapp.close()


async def test_mqtt_frames_carry_their_expiry_and_a_stale_one_is_dropped_by_the_broker(mosquitto):
    url = f"mqtt://127.0.0.1:{mosquitto.port}/"
    robot = await opened(url, "mqtt-stale")
    netapp = await opened(url, "mqtt-stale")
    seen: list = []

    async def keep(incoming) -> None:
        seen.append(incoming)
        await incoming.ack()

    await netapp.consume(keep)
    now = time.time_ns()
    frame = EncodedFrame(JPEG, 7, b"x", deadline_ms=1500)
    await robot.send(pack_frame(frame), Envelope("r", "s", "back", expires_ns(1500, now)), "7", frame.deadline_ms)
    assert await wait_until(lambda: seen)
    envelope = seen[0].envelope
    assert envelope == Envelope("r", "s", "back", expires_ns(1500, now)) and seen[0].correlation == "7"
    assert not envelope.stale(now) and envelope.stale(now + 2_000_000_000)
    await netapp.close()
    await robot.close()


async def test_mqtt_sockets_send_without_nagle(mosquitto):
    """paho leaves Nagle on: a result sent after a PUBACK waited for the broker's delayed ACK (+21 ms at 25 FPS)."""
    from netapp.broker.links.mqtt import MqttLink

    url = f"mqtt://127.0.0.1:{mosquitto.port}/?netapp=nagle"
    frames, link = MqttFrames(parse_broker_url(url)), MqttLink(parse_broker_url(url))
    await frames.connect()
    await link.connect()
    for client in (frames._client, link._client):
        assert client._client.socket().getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY)
    await frames.close()
    await link.close()
