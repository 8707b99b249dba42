"""Frames through a broker that restarts mid-stream, against a real RabbitMQ and Mosquitto of the test's own (the
session's brokers stay up for the other tests): the robot learns of the loss without a frame failing to go (its
transport watches the connection), and once the broker is back both ends connect again on their own and the robot's
frames are answered again. How fast is the bench's (bench/broker_restart.py), not asserted here."""

from __future__ import annotations

import time

import numpy as np
import pytest

pytest.importorskip("aio_pika")
pytest.importorskip("aiomqtt")

from netapp.broker.address import parse_broker_url  # noqa: E402
from netapp.client import NetAppClient  # noqa: E402
from netapp.server.settings import Settings  # noqa: E402
from tests.netapp.broker.conftest import installed  # noqa: E402
from tests.support.brokers import Mosquitto, RabbitMQ  # noqa: E402

FRAME = np.full((96, 128, 3), 120, np.uint8)


def poll(check, timeout_s: float) -> bool:
    """Until `check()` holds or `timeout_s` passes (polled every 20 ms); whether it held."""
    deadline = time.monotonic() + timeout_s
    while not check():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


def answered_after(client: NetAppClient, since_ns: int, timeout_s: float) -> bool:
    """Send a frame every 0.1 s (the newest wins while none can go) until one sent at or after `since_ns` (wall
    clock) is answered, or `timeout_s` passes."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        client.send(FRAME)
        for result in client.results(timeout=0.1):
            if result.timestamp >= since_ns:
                return True
    return False


@pytest.mark.parametrize("kind", ["amqp", "mqtt"])
def test_a_broker_restarted_mid_stream_is_streamed_through_again(serve, tiny_detector, kind):
    broker = installed(RabbitMQ if kind == "amqp" else Mosquitto)
    with broker:
        url = f"{broker.url.rstrip('/')}/?netapp=restart-{kind}"
        serve(tiny_detector, Settings(lanes=1, consume=(parse_broker_url(url),)))
        with NetAppClient(url, robot_id="robot-1") as client:
            assert answered_after(client, 0, 30)
            broker.down()
            # no frame sent meanwhile: the transport's watch tells the link
            assert poll(lambda: not client.connected, 10), "the robot did not notice the broker was gone"
            broker.start()
            back_ns = time.time_ns()
            assert answered_after(client, back_ns, 30), "no frame was answered after the broker came back"
            assert client.connected
