"""The robot's end of frames through a broker (netapp/client/transports/broker.py), against a real RabbitMQ,
Mosquitto and Kafka's mock cluster with a netapp's end that answers each frame: transmit never waits, results and
errors come back through the transport's callbacks, a superseded frame is told as dropped."""

from __future__ import annotations

import asyncio

import pytest

pytest.importorskip("aio_pika")
pytest.importorskip("aiomqtt")

from netapp.broker.address import parse_broker_url  # noqa: E402
from netapp.broker.channels import channel_for  # noqa: E402
from netapp.client.transports import SessionSettings, TransportCallbacks  # noqa: E402
from netapp.client.transports.broker import BrokerTransport  # noqa: E402
from netapp.frame import JPEG, EncodedFrame  # noqa: E402
from netapp.framing import ERROR_EVENT, event, parse_frame  # noqa: E402
from netapp.protocol import RESULTS_EVENT, SUPERSEDED_REASON  # noqa: E402
from tests.support.broker_readers import wait_until  # noqa: E402


async def test_frames_go_and_results_and_errors_come_back(broker_url):
    url = f"{broker_url}?netapp=robot-test"
    netapp = channel_for(parse_broker_url(url))
    await netapp.connect()
    seen = []

    async def answer(incoming) -> None:
        frame = parse_frame(incoming.body)
        seen.append((incoming.envelope, frame))
        if frame.timestamp == 2:  # newest wins: the netapp says it superseded this one
            text = event(ERROR_EVENT, {"timestamp": 2, "error": "superseded", "reason": SUPERSEDED_REASON})
        else:
            text = event(RESULTS_EVENT, {"timestamp": frame.timestamp, "detections": []})
        await netapp.reply(incoming.envelope, incoming.correlation, text.encode())
        await incoming.ack()

    await netapp.consume(answer)
    results, dropped, ready = [], [], []
    callbacks = TransportCallbacks(
        on_ready=lambda: ready.append(True),
        on_lost=lambda: None,
        on_result=results.append,
        on_error=lambda e: None,
        on_dropped=dropped.append,
        on_refused=lambda why: None,
        on_move=lambda why: None,
    )
    transport = BrokerTransport(url, SessionSettings(robot_id="robot-9"), callbacks)
    await asyncio.to_thread(transport.connect)
    assert ready and transport.session_id
    for timestamp in (1, 2, 3):
        transport.transmit(EncodedFrame(JPEG, timestamp, b"\xff\xd8", deadline_ms=2000))
    assert await wait_until(lambda: len(results) == 2 and dropped)
    assert [r["timestamp"] for r in results] == [1, 3] and dropped == [2]
    envelope = seen[0][0]
    assert envelope.robot == "robot-9" and envelope.session == transport.session_id and envelope.expires_ns
    await asyncio.to_thread(transport.close)
    await netapp.close()


def test_a_wrong_url_is_refused_before_anything_connects():
    callbacks = TransportCallbacks(*(lambda *a: None for _ in range(7)))
    with pytest.raises(ValueError, match="unknown option"):
        BrokerTransport("amqp://rabbit/?nope=1", SessionSettings(), callbacks)
