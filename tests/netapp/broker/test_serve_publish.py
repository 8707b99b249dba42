"""`netapp serve --publish`: a robot's results reach RabbitMQ and Mosquitto through the dataplane's observer
(netapp/server/brokers/), each message valid against the schema, keyed by the robot's id; the metrics count them
and show no password; a broker that is down delays no robot; a wrong URL stops the netapp with one line."""

from __future__ import annotations

import asyncio
import subprocess
import sys

import numpy as np
import pytest
import requests

pytest.importorskip("aio_pika")
pytest.importorskip("aiomqtt")

from netapp.broker.address import parse_broker_url  # noqa: E402
from netapp.client import NetAppClient  # noqa: E402
from netapp.server.settings import Settings  # noqa: E402
from tests.support.broker_readers import MqttReader, amqp_fetch, amqp_queue, wait_until  # noqa: E402
from tests.support.broker_schema import checked  # noqa: E402

FRAMES = 5


def send_frames(url: str, count: int, robot_id: str | None = "robot-1") -> list:
    frame = np.full((96, 128, 3), 120, np.uint8)
    results = []
    with NetAppClient(url, transport="http", robot_id=robot_id) as client:
        for _ in range(count):
            client.send(frame)
            results.append(next(client.results(timeout=10)))
    return results


async def test_a_robots_results_reach_rabbitmq_and_mqtt_valid_and_in_order(
    serve, tiny_detector, rabbitmq, mosquitto, tmp_path
):
    password = tmp_path / "password"
    password.write_text("guest")
    amqp = parse_broker_url(rabbitmq.url.replace("guest:guest@", "guest@") + f"?password_file={password}", "edge")
    mqtt = parse_broker_url(f"mqtt://127.0.0.1:{mosquitto.port}/", "edge")
    queue = await amqp_queue(rabbitmq.url, "results.edge.robot-1")
    async with MqttReader("127.0.0.1", mosquitto.port, "netapp/edge/+/results") as reader:
        server = serve(tiny_detector, Settings(lanes=1, publish=(amqp, mqtt)))
        results = await asyncio.to_thread(send_frames, server.url, FRAMES)
        assert await wait_until(lambda: len(reader.messages) == FRAMES)
    mqtt_messages = [checked(body) for _, body, _ in reader.messages]
    amqp_messages = [checked(body) for _, body in await amqp_fetch(rabbitmq.url, queue, FRAMES)]
    for messages in (mqtt_messages, amqp_messages):
        assert [m["capture_ns"] for m in messages] == [r.timestamp for r in results]  # in order, every one
        assert {m["source"] for m in messages} == {"robot-1"} and {m["netapp"] for m in messages} == {"edge"}
        first = messages[0]
        assert first["result"]["detections"][0]["class_name"] == "robot" and first["latency_ms"] > 0
        assert first["model"]["name"] == tiny_detector.name and len(first["model"]["sha256"]) == 64
    assert {topic for topic, _, _ in reader.messages} == {"netapp/edge/robot-1/results"}
    metrics = requests.get(server.url + "/metrics", timeout=5).text
    assert f'netapp_broker_published_total{{broker="{amqp.redacted()}"}} {float(FRAMES)}' in metrics
    assert f'netapp_broker_up{{broker="{mqtt.redacted()}"}} 1.0' in metrics
    assert "password" not in metrics and "guest@" in metrics and ":guest@" not in metrics


async def test_a_broker_that_is_down_delays_no_robot(serve, tiny_detector):
    down = parse_broker_url(f"mqtt://127.0.0.1:{_closed_port()}/?buffer=3", "edge")
    server = serve(tiny_detector, Settings(lanes=1, publish=(down,)))
    results = await asyncio.to_thread(send_frames, server.url, FRAMES, None)
    assert len(results) == FRAMES
    metrics = requests.get(server.url + "/metrics", timeout=5).text
    assert f'netapp_broker_up{{broker="{down.redacted()}"}} 0.0' in metrics
    assert f'netapp_broker_dropped_total{{broker="{down.redacted()}",reason="count"}} 2.0' in metrics
    assert f'netapp_broker_waiting{{broker="{down.redacted()}"}} 3.0' in metrics


def _closed_port() -> int:
    from netapp.serve_process import free_port

    return free_port()  # nothing listens there


def test_a_wrong_publish_url_stops_the_netapp_with_one_line_and_no_password(tiny_model_path):
    done = subprocess.run(
        [sys.executable, "-m", "netapp", "serve", "--model", str(tiny_model_path), "--port", "0"]
        + ["--publish", "amqp://user:hunter2@rabbit/?nope=1"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2
    assert "unknown option nope" in done.stderr and "hunter2" not in done.stderr + done.stdout
