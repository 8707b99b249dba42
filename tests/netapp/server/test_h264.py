"""The H.264 transport (`image_h264`): our client and an unmodified era-5g-client against a real server.

Frames are solid colours from a palette and the server's processor answers with the mean colour it decoded, so
every result checks the decoding of its own frame (a packet decoded out of order or from a broken reference
comes out in the wrong colour).
"""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import socketio

av = pytest.importorskip("av")

from netapp.client.netapp_client import NetAppClient  # noqa: E402
from netapp.protocol import CONTROL_NAMESPACE, DATA_NAMESPACE, H264_EVENT  # noqa: E402
from netapp.sdk.processor import Processor  # noqa: E402
from netapp.server.app import create_app  # noqa: E402
from netapp.server.decoding.h264_bitstream import contains_idr  # noqa: E402
from tests.support.h264_colours import DEADLINE_S, HEIGHT, WIDTH, assert_colour, colour_frame, stream_messages  # noqa: E402
from tests.support.servers import BackgroundServer  # noqa: E402


class ColourProcessor(Processor):
    """Answers each frame with its mean BGR colour and size: decoding correctness, no model needed."""

    name = "colour"

    def prepare(self, image: np.ndarray, args: Any) -> dict[str, Any]:
        return {"colour": image.reshape(-1, 3).mean(axis=0).round(1).tolist(), "size": [image.shape[1], image.shape[0]]}

    def process(self, batch: list[dict[str, Any]]) -> list[dict[str, Any]]:
        return [{**p, "detections": []} for p in batch]


class Server(BackgroundServer):
    """create_app(processor) on a free loopback port, with a look at its sessions' H.264 state."""

    def __init__(self, processor: Processor) -> None:
        self.app = create_app(processor)
        super().__init__(self.app)

    def h264_stream(self, session_id: str):
        return self.app.other_asgi_app.state.dataplane.connection(session_id).decoders[H264_EVENT]


def poll_until(condition, what: str, timeout_s: float = DEADLINE_S) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.01)  # polling a condition with a deadline


@pytest.fixture(scope="module")
def server() -> Iterator[Server]:
    with Server(ColourProcessor()) as srv:
        yield srv


class RawRobot:
    """A bare Socket.IO robot: INIT, then `image_h264` messages; replies (result or data_error) by timestamp."""

    def __init__(self, url: str) -> None:
        self.replies: dict[int, tuple[str, dict[str, Any]]] = {}
        self._cond = threading.Condition()
        self.sio = socketio.Client()
        self.sio.on("results", lambda m: self._reply("result", m), namespace=DATA_NAMESPACE)
        self.sio.on("data_error", lambda m: self._reply("error", m), namespace=DATA_NAMESPACE)
        self.sio.connect(url, namespaces=[DATA_NAMESPACE, CONTROL_NAMESPACE], wait_timeout=DEADLINE_S)
        ok, text = self.command(1)
        assert ok, text
        self.session_id = self.sio.eio.sid  # the server keys sessions by the Engine.IO sid

    def command(self, cmd_type: int) -> tuple[bool, str]:
        return self.sio.call(
            "command",
            {"cmd_type": cmd_type, "clear_queue": False, "data": {}},
            namespace=CONTROL_NAMESPACE,
            timeout=DEADLINE_S,
        )

    def _reply(self, kind: str, message: dict[str, Any]) -> None:
        with self._cond:
            self.replies[message["timestamp"]] = (kind, message)
            self._cond.notify_all()

    def send(self, message: dict[str, Any]) -> None:
        self.sio.emit(H264_EVENT, message, namespace=DATA_NAMESPACE)

    def reply(self, timestamp: int) -> tuple[str, dict[str, Any]]:
        with self._cond:
            assert self._cond.wait_for(lambda: timestamp in self.replies, DEADLINE_S), f"no reply for {timestamp}"
            return self.replies[timestamp]

    def exchange(self, message: dict[str, Any]) -> tuple[str, dict[str, Any]]:
        self.send(message)
        return self.reply(message["timestamp"])

    def close(self) -> None:
        self.sio.disconnect()


# -- against a real server ---------------------------------------------------------------------------------------


def test_netapp_client_gets_a_result_per_frame(server: Server) -> None:
    results: dict[int, dict[str, Any]] = {}
    cond = threading.Condition()

    def on_result(result) -> None:
        with cond:
            results[result.timestamp] = result.message
            cond.notify_all()

    with NetAppClient(server.url, transport="h264", max_in_flight=1, on_result=on_result) as client:
        for i in range(40):
            timestamp = client.send(colour_frame(i))
            with cond:
                assert cond.wait_for(lambda ts=timestamp: ts in results, DEADLINE_S), f"no result for frame {i}"
            assert_colour(results[timestamp], i)
            assert results[timestamp]["size"] == [WIDTH, HEIGHT]
        assert client.stats.errors == 0 and client.stats.results == 40


def test_client_restarts_its_stream_with_a_keyframe_after_a_decoder_error(server: Server, monkeypatch) -> None:
    """Recovery takes one frame, not a keyframe interval: the data_error's reason asks for a keyframe at once."""
    import netapp.client.h264 as client_h264

    encode = client_h264.encode_frame
    calls = []

    def damage_the_tenth(encoder, frame, timestamp, options, **settings):
        encoded, encoder = encode(encoder, frame, timestamp, options, **settings)
        calls.append(contains_idr(encoded.payload))
        if len(calls) == 10:
            encoded = replace(encoded, payload=encoded.payload[: len(encoded.payload) // 2])
        return encoded, encoder

    monkeypatch.setattr(client_h264, "encode_frame", damage_the_tenth)
    errors: list[dict[str, Any]] = []
    with NetAppClient(server.url, transport="h264", max_in_flight=1, on_error=errors.append) as client:
        for i in range(20):
            client.send(colour_frame(i))
            assert client.wait_idle(DEADLINE_S)
        results = list(client.results(timeout=0.1))  # all arrived: wait_idle saw every frame settled
    assert [e["reason"] for e in errors] == ["h264_decode_error"]
    assert len(results) == 19
    assert [i for i, key in enumerate(calls) if key] == [0, 10]  # the frame after the damaged one is a keyframe


@pytest.mark.parametrize("max_in_flight", [1, 2])
def test_back_pressure_drops_before_encoding(server: Server, monkeypatch, max_in_flight: int) -> None:
    """Frames offered much faster than served: the client drops some, the server decodes every packet it gets.

    With two in flight the robot's thread and the sender thread both transmit: they must still encode one frame
    at a time (libx264 hung when two threads entered it) and send packets in the order they were encoded."""
    import netapp.client.h264 as client_h264

    encode = client_h264.encode_frame
    lock = threading.Lock()
    inside = [0, 0]  # encoding now, most at once

    def counting(encoder, frame, timestamp, options, **settings):
        with lock:
            inside[0] += 1
            inside[1] = max(inside[1], inside[0])
        try:
            return encode(encoder, frame, timestamp, options, **settings)
        finally:
            with lock:
                inside[0] -= 1

    monkeypatch.setattr(client_h264, "encode_frame", counting)
    # This test is about the client's back-pressure: on a loaded machine the server's own overload guard (skip to
    # the next keyframe when packets wait too long or a stream uses its decode budget) must not step in.
    import netapp.server.decoding.h264 as server_h264

    monkeypatch.setattr(server_h264, "MAX_LAG_S", 60.0)
    monkeypatch.setattr(server_h264, "DECODE_BURST_S", 60.0)
    errors: list[dict[str, Any]] = []
    results: list[dict[str, Any]] = []
    with NetAppClient(
        server.url,
        transport="h264",
        max_in_flight=max_in_flight,
        on_error=errors.append,
        on_result=lambda r: results.append(r.message),
    ) as client:
        sent = {client.send(colour_frame(i)): i for i in range(300)}
        assert client.wait_idle(DEADLINE_S)
        assert server.h264_stream(client.session_id).decoder.resets == 0
    assert inside[1] == 1
    assert errors == []
    assert 0 < len(results) < 300  # some frames were dropped, in the client's slot, before encoding
    for message in results:
        assert_colour(message, sent[message["timestamp"]])


def test_fast_streams_decode_in_order_and_in_parallel(server: Server) -> None:
    """Three robots emit packets back to back, unthrottled: every reply is a correct picture, nothing is refused."""
    robots = [RawRobot(server.url) for _ in range(3)]
    count = 150
    messages = stream_messages(count, width=320, height=240)  # big enough that decodes overlap if unserialised

    def blast(robot: RawRobot) -> None:
        for message in messages:
            robot.send(message)
        robot.reply(count)  # the last frame is never dropped by the newest-wins queue

    with ThreadPoolExecutor(len(robots)) as pool:
        list(pool.map(blast, robots))
    for robot in robots:
        errors = [m for kind, m in robot.replies.values() if kind == "error" and m["reason"] != "superseded"]
        assert errors == []
        for timestamp, (kind, message) in robot.replies.items():
            if kind != "error":  # a superseded frame's data_error (newest wins) carries no picture
                assert_colour(message, timestamp - 1)
        assert server.h264_stream(robot.session_id).decoder.resets == 0
        robot.close()


def test_damaged_packet_resets_that_session_only(server: Server) -> None:
    damaged_at, count = 10, 40  # keyframes at 0 and 25
    victim, bystander = RawRobot(server.url), RawRobot(server.url)
    bystander_replies: list[tuple[str, dict[str, Any]]] = []

    def bystander_streams() -> None:
        for message in stream_messages(count):
            bystander_replies.append(bystander.exchange(message))

    thread = threading.Thread(target=bystander_streams)
    thread.start()
    replies = []
    for i, message in enumerate(stream_messages(count)):
        if i == damaged_at:
            message = {**message, "frame": message["frame"][: len(message["frame"]) // 2]}  # data lost on the way
        replies.append(victim.exchange(message))
    thread.join(DEADLINE_S)
    assert not thread.is_alive()

    assert all(kind == "result" for kind, _ in replies[:damaged_at])
    kind, message = replies[damaged_at]
    assert kind == "error" and "reset" in message["error"], message
    for kind, message in replies[damaged_at + 1 : 25]:
        assert kind == "error" and "keyframe" in message["error"], message
    for i in range(25, count):  # recovered at the keyframe
        kind, message = replies[i]
        assert kind == "result", message
        assert_colour(message, i)
    assert server.h264_stream(victim.session_id).decoder.resets == 1

    assert [kind for kind, _ in bystander_replies] == ["result"] * count
    for i, (_, message) in enumerate(bystander_replies):
        assert_colour(message, i)
    assert server.h264_stream(bystander.session_id).decoder.resets == 0
    victim.close()
    bystander.close()


def test_a_packet_lost_after_encoding_answers_an_error_not_a_damaged_picture(server: Server) -> None:
    robot = RawRobot(server.url)
    replies = [robot.exchange(m) for i, m in enumerate(stream_messages(27)) if i != 5]  # frame 5 never arrives
    kinds = [kind for kind, _ in replies]  # replies[i] is frame i for i < 5, frame i + 1 after
    assert kinds == ["result"] * 5 + ["error"] * 19 + ["result"] * 2, kinds
    assert "missing" in replies[5][1]["error"]
    assert_colour(replies[-1][1], 26)
    robot.close()


def test_missing_size_and_older_timestamp_are_refused(server: Server) -> None:
    robot = RawRobot(server.url)
    first, second, third = stream_messages(3)
    kind, message = robot.exchange({"timestamp": 5, "frame": first["frame"]})
    assert kind == "error" and "width" in message["error"] and "height" in message["error"]
    kind, message = robot.exchange({**first, "timestamp": 1000})
    assert kind == "result"
    kind, message = robot.exchange({**second, "timestamp": 500})
    assert kind == "error" and "older" in message["error"], message
    # The refused packet was still decoded: the next one, which references it, comes out right.
    kind, message = robot.exchange({**third, "timestamp": 2000})
    assert kind == "result", message
    assert_colour(message, 2)
    kind, message = robot.exchange({**third, "timestamp": 3000, "width": 0})
    assert kind == "error" and "width" in message["error"]
    # That packet was not decoded, so the stream resumes at the next keyframe only.
    kind, message = robot.exchange({**third, "timestamp": 4000})
    assert kind == "error" and "keyframe" in message["error"]
    kind, message = robot.exchange({**first, "timestamp": 5000})
    assert kind == "result"
    assert_colour(message, 0)
    robot.close()


def test_reset_state_waits_for_the_next_keyframe(server: Server) -> None:
    robot = RawRobot(server.url)
    messages = stream_messages(12, {"g": "10"})
    assert robot.exchange(messages[0])[0] == "result"
    assert robot.command(2)[0]  # RESET_STATE
    for message in messages[1:10]:
        kind, reply = robot.exchange(message)
        assert kind == "error" and "keyframe" in reply["error"]
    for i in (10, 11):
        kind, reply = robot.exchange(messages[i])
        assert kind == "result", reply
        assert_colour(reply, i)
    robot.close()


def test_unmodified_era_5g_client_streams_h264(server: Server) -> None:
    client_base = pytest.importorskip("era_5g_client.client_base")
    from era_5g_interface.channels import CallbackInfoClient, ChannelType

    results: dict[int, dict[str, Any]] = {}
    cond = threading.Condition()

    def on_results(message: dict[str, Any]) -> None:
        with cond:
            results[message["timestamp"]] = message
            cond.notify_all()

    client = client_base.NetAppClientBase({"results": CallbackInfoClient(ChannelType.JSON, on_results)})
    client.register(server.url)
    session_id = client._sio.eio.sid
    try:
        for i in range(30):
            timestamp = time.perf_counter_ns()
            client.send_image(colour_frame(i), "image_h264", ChannelType.H264, timestamp)
            with cond:
                assert cond.wait_for(lambda ts=timestamp: ts in results, DEADLINE_S), f"no result for frame {i}"
            assert_colour(results[timestamp], i)
        assert server.h264_stream(session_id).decoder.resets == 0
    finally:
        # python-engineio's threaded client can lose a race between disconnect() and its write loop, which then
        # waits out ping_interval + 5 s (upstream, seen with H.264 timing): disconnect in the background and wait
        # for the server to close the session instead.
        threading.Thread(target=client.disconnect, daemon=True).start()
    sessions = server.app.other_asgi_app.state.netapp.sessions
    poll_until(lambda: sessions.get(session_id) is None, "the server to close the era client's session")


def test_real_detections_over_h264(real_model_path: Path, media_dir: Path) -> None:
    from netapp.client.sources import open_source
    from netapp.models import Detector, DetectorConfig

    frames = list(itertools.islice(open_source(str(media_dir / "pedestrians.avi"), 10, (640, 480)), 20))
    with Server(Detector(DetectorConfig(str(real_model_path)))) as srv:
        with NetAppClient(srv.url, transport="h264", max_in_flight=1) as client:
            for frame in frames:
                client.send(frame)
                assert client.wait_idle(60)
            results = list(client.results(timeout=1))
            assert client.stats.errors == 0, client.stats.last_error
    assert len(results) == len(frames)
    people = [sum(d["class_name"] == "person" for d in r.detections) for r in results]
    assert min(people) >= 5, people  # about 15-20 people walk across the hall, as over JPEG
