"""bench/broker.py on a small scale: its sample result is a valid broker message, and the broker-away part bounds the
buffer, counts the overflow and drains once Mosquitto is back."""

from __future__ import annotations

import pytest

pytest.importorskip("aiomqtt")

from bench.broker import away, sample_body  # noqa: E402
from tests.support.broker_schema import checked  # noqa: E402
from tests.support.brokers import MOSQUITTO_HINT, Mosquitto  # noqa: E402


def test_the_sample_result_is_a_valid_message_of_about_a_kilobyte():
    body = sample_body(0)
    assert len(checked(body)["result"]["detections"]) == 10 and 1000 < len(body) < 4000


async def test_away_bounds_the_buffer_counts_overflow_and_drains():
    try:
        Mosquitto().stop()
    except FileNotFoundError:
        pytest.skip(MOSQUITTO_HINT)
    found = await away(1.0, 100.0, 20)
    assert found["offered"] > 40 and found["dropped"]["count"] == found["offered"] - 20
    assert found["sent_after"] == 20 and found["drained_s"] < 5
