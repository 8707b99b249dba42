"""A result back over UDP: compressed into one datagram, and what comes in bounded before it is inflated."""

from __future__ import annotations

import json
import random
import zlib

import pytest

from netapp.rtp.packet import MAX_DATAGRAM_BYTES, RESULT_APP, app
from netapp.rtp.results import MAX_RESULT_BYTES, result_datagram, result_json


def crowd(people: int) -> bytes:
    detections = [
        {"bbox": [10.5 * k, 20.25 + k, 60.5 * k, 200.75], "score": 0.8123, "class_id": 0, "class_name": "person"}
        for k in range(people)
    ]
    return json.dumps({"timestamp": 123456789, "detections": detections}).encode()


def test_a_crowds_result_fits_one_datagram_and_reads_back():
    text = crowd(60)
    assert len(text) > 3 * MAX_DATAGRAM_BYTES  # it would not fit as it is
    datagram = result_datagram(7, text)
    assert len(datagram) <= MAX_DATAGRAM_BYTES and len(datagram) % 4 == 0
    assert result_json(datagram, 7) == text
    assert result_json(datagram, 8) is None  # from another SSRC: not the netapp's


def test_what_does_not_fit_is_refused_for_the_transport_to_carry():
    with pytest.raises(ValueError):
        result_datagram(7, random.Random(1).randbytes(16384))  # 16 KB that does not compress
    with pytest.raises(ValueError):
        result_datagram(7, b" " * (MAX_RESULT_BYTES + 1))


def test_hostile_result_datagrams_are_ignored():
    bomb = zlib.compress(b"0" * (4 * MAX_RESULT_BYTES), 9)  # 1 MB in a datagram
    assert len(bomb) < 1400 and result_json(app(7, RESULT_APP, bomb), 7) is None
    assert result_json(app(7, RESULT_APP, b"not zlib"), 7) is None
    cut = zlib.compress(crowd(5))[:-6]
    assert result_json(app(7, RESULT_APP, cut), 7) is None
    assert result_json(b"\x80\xcc\x00\x00", 7) is None
