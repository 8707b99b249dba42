"""netapp.wire_json: the data path's JSON, the same text as the standard library's where that is valid JSON, on the
safe side where it is not, and usable as python-socketio's `json` (both sides)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from socketio.packet import Packet

from netapp import wire_json
from netapp.client.transports.socketio import WirePacket
from netapp.server.sio.limits import bounded_packet_class


def test_a_result_reads_back_as_the_standard_library_reads_it():
    result = {"timestamp": 1732500000123456789, "detections": [{"bbox": [1.5, 2.25, 3.0, 4.0], "score": 0.85}]}
    text = wire_json.dumps(result)
    assert json.loads(text) == result == wire_json.loads(text) == wire_json.loads(text.encode())


def test_what_the_standard_library_gets_wrong_or_refuses():
    assert wire_json.dumps({"score": math.nan, "far": math.inf}) == '{"score":null,"far":null}'  # `NaN` is no JSON
    assert json.loads(wire_json.dumps({1: "a"})) == {"1": "a"}  # as json.dumps does
    assert json.loads(wire_json.dumps({"box": np.array([1.5, 2.0], np.float32), "n": np.int64(3)})) == {
        "box": [1.5, 2.0],
        "n": 3,
    }
    with pytest.raises(TypeError):
        wire_json.dumps({"frame": b"\xff\xd8"})


def test_not_json_is_a_value_error():
    for text in ("{", "NaN", b"\xff", '{"a": 1} x'):
        with pytest.raises(ValueError):
            wire_json.loads(text)


def test_socketio_packets_on_both_sides_use_it_and_nobody_elses_change():
    assert WirePacket.json is wire_json and bounded_packet_class(1, 1).json is wire_json
    assert Packet.json is not wire_json  # a robot's own Socket.IO clients keep the standard library
    packet = WirePacket(data=["results", {"score": math.nan}], namespace="/data")
    assert packet.encode() == '2/data,["results",{"score":null}]'
