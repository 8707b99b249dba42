"""`netapp serve --consume`: frames from a broker's work queue, answered at each robot's reply address, against a
real RabbitMQ and Mosquitto, and Kafka (librdkafka's mock cluster, a test double of the protocol, not Kafka, unless
KAFKA_BOOTSTRAP names a real one): a robot's NetAppClient on an amqp://, mqtt:// or kafka:// URL gets the same
results as on the other transports (and they are published as well); a stale frame is never answered; a poison or
oversized one is refused before it is decoded and dead-lettered (RabbitMQ) or skipped and committed (Kafka), never
redelivered; a robot that floods starves nobody."""

from __future__ import annotations

import asyncio
import time
import uuid

import numpy as np
import pytest
import requests

pytest.importorskip("aio_pika")
pytest.importorskip("aiomqtt")

from netapp.broker.address import parse_broker_url  # noqa: E402
from netapp.broker.channels import channel_for  # noqa: E402
from netapp.broker.frames import Envelope  # noqa: E402
from netapp.client import NetAppClient  # noqa: E402
from netapp.frame import JPEG, EncodedFrame  # noqa: E402
from netapp.framing import pack_frame  # noqa: E402
from netapp.server.settings import Settings  # noqa: E402
from tests.support.broker_readers import MqttReader, amqp_fetch, kafka_committed, wait_until  # noqa: E402
from tests.support.broker_schema import checked  # noqa: E402
from tests.support.images import make_jpeg  # noqa: E402

FRAME = np.full((96, 128, 3), 120, np.uint8)


def stream(url: str, count: int, robot_id: str = "robot-1") -> list:
    with NetAppClient(url, robot_id=robot_id) as client:
        results = []
        for _ in range(count):
            client.send(FRAME)
            results.append(next(client.results(timeout=15)))
    return results


async def test_a_robot_streams_through_the_broker_and_gets_its_results(serve, tiny_detector, broker_url, mosquitto):
    name = f"consume-{broker_url[:4]}-{uuid.uuid4().hex[:6]}"  # a real Kafka keeps its groups between runs
    consume = parse_broker_url(f"{broker_url}?netapp={name}")
    publish = parse_broker_url(f"mqtt://127.0.0.1:{mosquitto.port}/", name)
    async with MqttReader("127.0.0.1", mosquitto.port, f"netapp/{name}/+/results") as reader:
        server = serve(tiny_detector, Settings(lanes=1, consume=(consume,), publish=(publish,)))
        results = await asyncio.to_thread(stream, f"{broker_url}?netapp={name}", 5)
        assert await wait_until(lambda: len(reader.messages) == 5)
    assert all(r.detections and r.detections[0]["class_name"] == "robot" for r in results)
    assert results[0].breakdown is not None  # the timing breakdown, as on every transport
    # no promise of a turn where the robot's next frame may go to another replica on the queue (the pacer would hold
    # the robot to this replica's schedule, and a second replica would wait for frames); Kafka keeps a robot at one
    promised = consume.kind == "kafka"
    assert all("input_size" in r.message["hint"] for r in results)
    assert all(("next_frame_in_ms" in r.message["hint"]) == promised for r in results)
    published = [checked(body) for _, body, _ in reader.messages]
    assert [m["capture_ns"] for m in published] == [r.timestamp for r in results]
    assert {m["source"] for m in published} == {"robot-1"}
    metrics = requests.get(server.url + "/metrics", timeout=5).text
    assert f'netapp_frames_processed_total{{transport="broker-{consume.kind}"}} 5.0' in metrics


async def send_raw(url: str, bodies: list[bytes], envelope: Envelope) -> None:
    robot = channel_for(parse_broker_url(url))
    await robot.connect()
    for n, body in enumerate(bodies):
        await robot.send(body, envelope, str(n), None)
    await robot.close()


@pytest.fixture(params=["amqp", "kafka"])
def queue_url(request) -> str:
    """RabbitMQ, and Kafka (librdkafka's mock cluster, a test double, unless KAFKA_BOOTSTRAP names a real one)."""
    if request.param == "kafka":
        pytest.importorskip("confluent_kafka")
        return request.getfixturevalue("kafka_url")
    return request.getfixturevalue("rabbitmq").url


async def never_redelivered(url: str, name: str) -> bool:
    """Whether the two poison frames were dead-lettered once each (RabbitMQ, the stale one not kept) or all three
    frames committed by the netapp's consumer group (Kafka: skipped, never read again)."""
    if url.startswith("amqp"):
        dead = await amqp_fetch(url, f"netapp.dead.{name}", 2)
        return sorted(len(body) for _, body in dead) == [25, 50_000]
    bootstrap = url.removeprefix("kafka://").rstrip("/")
    return await wait_until(lambda: kafka_committed(bootstrap, name, f"netapp.frames.{name}") == 3, 30)


async def test_stale_poison_and_oversized_frames(serve, tiny_detector, queue_url):
    name = f"poison-{uuid.uuid4().hex[:6]}"
    url = f"{queue_url}?netapp={name}"
    server = serve(tiny_detector, Settings(lanes=1, consume=(parse_broker_url(url),), max_payload_bytes=10_000))
    stale = Envelope("r", "s1", "netapp.replies", expires_ns=time.time_ns() - 1)
    fresh = Envelope("r", "s2", "netapp.replies")
    await send_raw(url, [pack_frame(EncodedFrame(JPEG, 1, make_jpeg()))], stale)
    await send_raw(url, [b"\x09" + b"x" * 24, b"\x01" * 50_000], fresh)
    transport = f"broker-{queue_url.partition(':')[0]}"

    def rejected(reason: str) -> str:
        return f'netapp_frames_rejected_total{{reason="{reason}",transport="{transport}"}} 1.0'

    def counted() -> bool:
        metrics = requests.get(server.url + "/metrics", timeout=5).text
        return all(rejected(r) in metrics for r in ("stale", "unknown_kind", "payload_too_large"))

    assert await wait_until(counted, 20)
    assert await never_redelivered(queue_url, name)


async def test_a_robot_that_floods_starves_nobody(serve, tiny_detector, queue_url):
    url = f"{queue_url}?netapp=fair-{uuid.uuid4().hex[:6]}"
    serve(tiny_detector, Settings(lanes=1, consume=(parse_broker_url(url),)))
    flood = [pack_frame(EncodedFrame(JPEG, n, make_jpeg())) for n in range(300)]
    flooding = asyncio.create_task(send_raw(url, flood, Envelope("flooder", "f", "netapp.replies")))
    results = await asyncio.to_thread(stream, url, 10, "polite")
    await flooding
    assert len(results) == 10


async def test_netapp_stream_through_the_broker_saves_and_writes_as_on_every_transport(
    serve, tiny_detector, broker_url, tmp_path, capsys
):
    """`netapp stream URL --save --jsonl` with the broker's URL: the same video and records as on the other
    transports (tests/netapp/client/test_stream_outputs.py)."""
    import cv2

    from tests.netapp.client.test_stream_outputs import check_boxes_drawn, stream_and_save

    url = f"{broker_url}?netapp=stream-{uuid.uuid4().hex[:6]}"
    serve(tiny_detector, Settings(lanes=1, consume=(parse_broker_url(url),)))
    await asyncio.to_thread(stream, url, 1)  # the netapp consumes (a Kafka group takes seconds to join)
    source = tmp_path / "grey.png"
    cv2.imwrite(str(source), np.full((160, 160, 3), 90, np.uint8))
    summary, records, frames = await asyncio.to_thread(stream_and_save, url, source, tmp_path, capsys, "--adapt", "off")
    check_boxes_drawn(source, records, frames)
    assert summary["frame_size"] == "160x160" and records[0]["breakdown_ms"]["inference_ms"] > 0
