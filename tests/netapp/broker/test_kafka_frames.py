"""Frames through Kafka, both ends of the channel (netapp/broker/channels/kafka.py), against librdkafka's mock cluster
(confluent-kafka's `test.mock.num.brokers`: a test double of the Kafka protocol on a real loopback port, not Kafka)
unless KAFKA_BOOTSTRAP names a real Kafka, which they then run against: a robot's frame reaches the consumer group
with its envelope in headers and its answer comes back on the replies topic keyed by the robot, to that robot's
session only; the consumer holds at most its prefetch; what is settled is committed, never read again by the group,
while what was handed over and not settled is; headers no robot would send are a problem, not a crash."""

from __future__ import annotations

import asyncio
import time
import uuid

import pytest

pytest.importorskip("confluent_kafka")

from netapp.broker.address import parse_broker_url  # noqa: E402
from netapp.broker.channels.kafka import KafkaFrames, Pending, consumer_config  # noqa: E402
from netapp.broker.frames import Envelope, expires_ns  # noqa: E402
from netapp.frame import JPEG, EncodedFrame  # noqa: E402
from netapp.framing import pack_frame, parse_frame  # noqa: E402
from tests.support.broker_readers import echoing, kafka_messages, wait_until  # noqa: E402


def test_the_committed_offset_never_passes_a_frame_still_being_answered():
    pending = Pending()
    for offset in (5, 6, 7):
        pending.taken(0, offset)
    assert pending.settled(0, 6) == 5  # 5 is still being answered: a new owner reads it again
    assert pending.settled(0, 6) is None  # settled once
    assert pending.settled(0, 5) == 7
    assert pending.settled(0, 7) == 8


def test_the_consumer_is_the_netapps_group_and_fetches_ahead_within_bounds():
    config = consumer_config(parse_broker_url("kafka://k1,k2:9093/?netapp=edge-1&prefetch=4"))
    assert config["group.id"] == "edge-1" and config["bootstrap.servers"] == "k1:9092,k2:9093"
    assert config["enable.auto.offset.store"] is False  # an offset is stored once its frame is settled
    assert config["queued.min.messages"] == 4 and config["queued.max.messages.kbytes"] <= 8 * 1024
    assert config["receive.message.max.bytes"] <= 16 * 2**20 + 512
    # librdkafka's default (1 s) held a partition to one prefetch a second: a flood starved the robot behind it
    assert config["fetch.queue.backoff.ms"] <= 10


async def opened(url: str, name: str, **options) -> KafkaFrames:
    query = "&".join(f"{k}={v}" for k, v in {"netapp": name, **options}.items())
    channel = KafkaFrames(parse_broker_url(f"{url}?{query}"))
    await channel.connect()
    return channel


def unique(name: str) -> str:
    return f"{name}-{uuid.uuid4().hex[:8]}"  # a real Kafka keeps its topics and groups between runs


async def test_a_frame_goes_to_the_group_and_its_answer_to_the_robots_session(kafka_url):
    name = unique("echo")
    netapp, robot, other = [await opened(kafka_url, name) for _ in range(3)]
    replies: dict[str, list[bytes]] = {"robot": [], "other": []}

    def keep(who: str):
        async def append(body: bytes) -> None:
            replies[who].append(body)

        return append

    reply_to = await robot.open_replies("session-1", keep("robot"))
    assert reply_to == "netapp.replies"
    await other.open_replies("session-2", keep("other"))  # the same topic: it must not read session-1's answer

    await netapp.consume(echoing(netapp))
    frame = EncodedFrame(JPEG, 123, b"\xff\xd8jpeg", deadline_ms=30_000)
    envelope = Envelope("robot-1", "session-1", reply_to, expires_ns(30_000, time.time_ns()))
    await robot.send(pack_frame(frame), envelope, "123", frame.deadline_ms)
    assert await wait_until(lambda: replies["robot"], 30)
    assert b'"robot":"robot-1"' in replies["robot"][0] and b'"timestamp":123' in replies["robot"][0]
    bootstrap = kafka_url.removeprefix("kafka://").rstrip("/")
    keys = [key for key, _ in await asyncio.to_thread(kafka_messages, bootstrap, f"netapp.frames.{name}", 1)]
    assert keys == [b"robot-1"]  # each robot's frames in order on one partition
    assert replies["other"] == []
    for channel in (robot, other, netapp):
        await channel.close()


async def test_a_channel_closed_connects_again(kafka_url):
    """The robot's transport closes its channel and connects the same one again after a loss (a broker back)."""
    name = unique("again")
    netapp, robot = [await opened(kafka_url, name) for _ in range(2)]
    await netapp.consume(echoing(netapp))
    replies: list[bytes] = []

    async def keep(body: bytes) -> None:
        replies.append(body)

    await robot.open_replies("session-1", keep)
    await robot.close()
    await robot.connect()
    reply_to = await robot.open_replies("session-1", keep)
    envelope = Envelope("robot-1", "session-1", reply_to, expires_ns(30_000, time.time_ns()))
    await robot.send(pack_frame(EncodedFrame(JPEG, 7, b"\xff\xd8jpeg", deadline_ms=30_000)), envelope, "7", 30_000)
    assert await wait_until(lambda: replies, 30)
    for channel in (robot, netapp):
        await channel.close()


async def test_the_consumer_holds_at_most_its_prefetch_and_what_it_settled_is_not_read_again(kafka_url):
    name = unique("held")
    robot = await opened(kafka_url, name)
    for n in range(10):
        envelope = Envelope(f"r{n % 3}", "s", "netapp.replies")
        await robot.send(pack_frame(EncodedFrame(JPEG, n, b"x")), envelope, str(n), None)
    netapp = await opened(kafka_url, name, prefetch=3)
    held: list = []

    async def hold(incoming) -> None:
        held.append(incoming)  # settled below, by hand

    await netapp.consume(hold)
    assert await wait_until(lambda: len(held) == 3, 30)
    await asyncio.sleep(0.3)
    assert len(held) == 3  # the other 7 wait: fetched ahead by librdkafka at most, never handed over
    for incoming in held[:3]:
        await incoming.ack()
    assert await wait_until(lambda: len(held) == 6, 30)
    settled = {parse_frame(i.body).timestamp for i in held[:3]}
    await netapp.close()  # 3 settled and committed, 3 handed over and not settled
    again = await opened(kafka_url, name)
    seen: list = []

    async def keep(incoming) -> None:
        seen.append(parse_frame(incoming.body).timestamp)
        await incoming.ack()

    await again.consume(keep)
    assert await wait_until(lambda: len(seen) == 7, 30)
    assert not settled & set(seen)  # the group's next owner reads what was not settled, and nothing settled
    await again.close()
    await robot.close()


async def test_headers_that_are_not_a_robots_are_a_problem_not_a_crash(kafka_url):
    from confluent_kafka import Producer

    name = unique("hostile")
    netapp = await opened(kafka_url, name)
    seen: list = []

    async def keep(incoming) -> None:
        seen.append(incoming)
        await incoming.reject()

    await netapp.consume(keep)
    producer = Producer({"bootstrap.servers": kafka_url.removeprefix("kafka://").rstrip("/")})
    topic = f"netapp.frames.{name}"
    producer.produce(topic, b"x", headers=[("robot_id", b"r" * 1000), ("session", b"s"), ("reply_to", b"t")])
    producer.produce(topic, b"x", headers=[("robot_id", b"r"), ("session", b"s"), ("reply_to", b"__consumer_offsets")])
    producer.produce(topic, None, headers=[("robot_id", None), ("session", b"\xff\xfe")])
    await asyncio.to_thread(producer.flush, 10)
    assert await wait_until(lambda: len(seen) == 3, 30)
    assert all(i.envelope is None for i in seen)
    assert sorted(i.problem.split(" ")[0] for i in seen) == ["a", "a", "reply_to"]
    await netapp.close()


async def test_two_replicas_share_the_group_and_each_robot_stays_on_one(kafka_url):
    name = unique("replicas")
    replicas = [await opened(kafka_url, name) for _ in range(2)]
    robots: list[dict[str, int]] = [{}, {}]  # per replica: robot -> frames it took

    def keep(index: int):
        async def take(incoming) -> None:
            robots[index][incoming.envelope.robot] = robots[index].get(incoming.envelope.robot, 0) + 1
            await incoming.ack()

        return take

    for index, replica in enumerate(replicas):
        await replica.consume(keep(index))

    topic = f"netapp.frames.{name}"
    found = await asyncio.to_thread(replicas[0]._consumer.list_topics, topic, timeout=10)
    if len(found.topics[topic].partitions) < 2:  # a real Kafka makes num.partitions, 1 by default
        pytest.skip(f"{topic} has one partition (the broker's num.partitions): one replica holds it all")

    def assigned() -> list[int]:
        return [len(replica._consumer.assignment()) for replica in replicas]

    # the group settled: each replica holds partitions of its own (the mock cluster makes topics of 4 partitions)
    assert await wait_until(lambda: all(assigned()), 60), assigned()
    sender = await opened(kafka_url, name)
    for n in range(64):
        envelope = Envelope(f"robot-{n % 16}", f"s{n % 16}", "netapp.replies")
        await sender.send(pack_frame(EncodedFrame(JPEG, n, b"x")), envelope, str(n), None)
    assert await wait_until(lambda: sum(sum(r.values()) for r in robots) == 64, 30)
    assert robots[0] and robots[1]  # both replicas served
    assert not set(robots[0]) & set(robots[1])  # each robot at one replica, where its newest frame wins
    for channel in (*replicas, sender):
        await channel.close()
