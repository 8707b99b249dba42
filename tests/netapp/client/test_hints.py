"""Hints from the netapp (issue 21, item 4): every result says the processor's size; the client bounds what it
reads, converges on a size that changed, and ignores a malformed hint with one log line."""

from __future__ import annotations

import logging
import math

import cv2
import numpy as np
import pytest
import requests

from netapp.client import NetAppClient
from netapp.client.hints import Hint, HintReader, check_input_size, parse_hint
from netapp.client.stats import ClientStats
from netapp.server.settings import Settings
from tests.support.polling import wait_until
from tests.support.processors import ShapeRecorder

HD = (1280, 720)
FRAME = np.full((HD[1], HD[0], 3), 90, np.uint8)


# -- pure: the bounds ---------------------------------------------------------------------------------------------


def test_a_valid_hint_is_taken_as_it_is() -> None:
    assert parse_hint({"input_size": [416, 416], "next_frame_in_ms": 12.5}, HD) == Hint((416, 416), 12.5)
    assert parse_hint({"next_frame_in_ms": 0}) == Hint(None, 0.0)
    assert parse_hint({}) == Hint()
    assert parse_hint(None) is None


@pytest.mark.parametrize(
    "raw",
    [
        {"input_size": [9000, 416]},  # too big
        {"input_size": [416, -416]},  # negative
        {"input_size": [16, 16]},  # below the floor
        {"input_size": [416.0, 416]},  # not integers
        {"input_size": [True, 416]},
        {"input_size": "416x416"},
        {"input_size": [416, 416, 3]},
        {"input_size": {"w": 416}},
        {"next_frame_in_ms": math.nan},
        {"next_frame_in_ms": math.inf},
        {"next_frame_in_ms": -1},
        {"next_frame_in_ms": 10_001},
        {"next_frame_in_ms": "12"},
        {"next_frame_in_ms": True},
        "a string",
        [416, 416],
    ],
)
def test_a_malformed_hint_is_ignored(raw) -> None:
    assert parse_hint(raw, HD) is None


def test_never_more_pixels_than_the_source() -> None:
    width, height = check_input_size([4096, 4096], HD)
    assert width * height <= HD[0] * HD[1] and width == height  # the same shape, the source's pixel count
    assert parse_hint({"input_size": [8192, 8192]}, (40, 20)) == Hint((32, 32))  # never below the floor
    assert check_input_size([640, 640], HD) == (640, 640)


# -- a real netapp on loopback ---------------------------------------------------------------------------------------


def test_every_transport_carries_the_hint(serve) -> None:
    server = serve(ShapeRecorder((416, 320)))
    for transport in ("ws", "http"):
        with NetAppClient(server.url, transport=transport) as client:
            client.send(FRAME)
            [result] = wait_until(lambda c=client: list(c.results(timeout=0)), what="a result")
            hint = result.message["hint"]
            assert hint["input_size"] == [416, 320] and 0 <= hint["next_frame_in_ms"] <= 1000  # and the next turn
            assert client.hints[server.url].input_size == (416, 320)
    session = requests.post(f"{server.url}/register", json={}, timeout=5).json()["session_id"]
    headers = {"X-Session-Id": session, "Content-Type": "image/jpeg", "X-Timestamp": "7"}
    jpeg = cv2.imencode(".jpg", FRAME)[1].tobytes()
    assert requests.post(f"{server.url}/send_image", data=jpeg, headers=headers, timeout=5).status_code == 202

    def polled():
        return requests.get(f"{server.url}/results", headers={"X-Session-Id": session}, timeout=5).json()["results"]

    [message] = wait_until(polled, what="a polled result")
    assert message["timestamp"] == 7 and message["hint"]["input_size"] == [416, 320]


def test_no_size_hint_from_a_processor_that_takes_any_size(serve) -> None:
    server = serve(ShapeRecorder(None))
    with NetAppClient(server.url, transport="ws") as client:
        client.send(FRAME)
        [result] = wait_until(lambda: list(client.results(timeout=0)), what="a result")
    assert list(result.message["hint"]) == ["next_frame_in_ms"] and client.stats.bad_hints == 0
    quiet = serve(ShapeRecorder(None), Settings(lanes=1, next_turn_hint=False))  # nothing to say at all: no hint
    with NetAppClient(quiet.url, transport="ws") as client:
        client.send(FRAME)
        [result] = wait_until(lambda: list(client.results(timeout=0)), what="a result")
    assert "hint" not in result.message


@pytest.mark.parametrize("transport", ["ws", "http", "frames"])
def test_the_robot_converges_on_a_size_the_netapp_changed(serve, transport) -> None:
    processor = ShapeRecorder(None)  # says nothing when the robot connects
    server = serve(processor)
    with NetAppClient(server.url, transport=transport, max_in_flight=1) as client:
        assert client.input_sizes == {server.url: None}
        processor.input_size = (208, 208)  # as if the netapp loaded another model
        for _ in range(3):
            client.send(FRAME)
            wait_until(lambda: list(client.results(timeout=0)), what="a result")
        assert client.input_sizes == {server.url: (208, 208)}
    assert processor.sizes == [HD, (208, 118), (208, 118)]  # the first went before the hint came


class HintingProcessor(ShapeRecorder):
    """A processor whose output carries a malformed `hint` of its own (the netapp, with no size to say and its
    next-turn hint off, adds none): stands for a hostile or broken netapp."""

    def process(self, batch):
        return [{"detections": [], "hint": {"input_size": [1, 99999], "next_frame_in_ms": "soon"}} for _ in batch]


def test_a_malformed_hint_is_counted_and_logged_once(serve, caplog) -> None:
    server = serve(HintingProcessor(None), Settings(lanes=1, next_turn_hint=False))
    caplog.set_level(logging.WARNING, logger="netapp.client.hints")
    with NetAppClient(server.url, transport="ws", max_in_flight=1) as client:
        for _ in range(4):
            client.send(FRAME)
            wait_until(lambda: list(client.results(timeout=0)), what="a result")
        assert client.stats.bad_hints == 4 and client.stats.results == 4
        assert client.input_sizes == {server.url: None} and client.stats.sent_size == HD
    assert len([r for r in caplog.records if "malformed hint" in r.message]) == 1


@pytest.mark.parametrize("raw", ["../../etc/passwd", "a/b", "", "x" * 65, 3, ["yolox_nano"], "-leading"])
def test_an_accuracy_profile_name_from_the_network_is_a_plain_name_or_nothing(raw) -> None:
    stats = ClientStats()
    reader = HintReader(stats)
    assert reader.read_profile_name(raw, "http://netapp") is None
    assert stats.bad_hints == 1
    assert reader.read_profile_name("yolox_nano", "http://netapp") == "yolox_nano"
    assert reader.read_profile_name(None, "http://netapp") is None and stats.bad_hints == 1
