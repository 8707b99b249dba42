"""The Socket.IO transport speaks 5G-ERA: raw protocol checks, bad input, and an unmodified era-5g-client robot."""

from __future__ import annotations

import json
import threading
import time

import numpy as np
import pytest

from tests.support.attacks import corrupt_jpeg
from tests.support.era_robot import era_robot
from tests.support.images import make_jpeg
from tests.support.onnx_models import TINY_NAMES
from tests.support.raw_robot import RawRobot


@pytest.fixture
def robot(tiny_server):
    robots = []

    def connect():
        robots.append(RawRobot(tiny_server.url))
        return robots[-1]

    yield connect
    for r in robots:
        r.close()


def test_init_stream_results(robot):
    r = robot()
    assert tuple(r.init(robot_id="r1")) == (True, "initialized")
    r.frame({"timestamp": 42, "frame": make_jpeg(), "metadata": {"seq": 1}})
    result = r.next("results")
    assert result["timestamp"] == 42
    assert {"recv_timestamp", "timestamp_before_process", "timestamp_after_process", "send_timestamp"} <= result.keys()
    assert result["detections"][0]["class_name"] == TINY_NAMES[2]


def test_second_init_and_malformed_commands_are_refused(robot):
    r = robot()
    assert r.init()[0] is True
    ok, message = r.init()
    assert ok is False and "already initialized" in message
    assert "already initialized" in r.next("command_error")["error"]
    ok, message = r.command({"no": "cmd_type"})
    assert ok is False and "malformed command" in r.next("command_error")["error"]
    ok, message = r.command({"cmd_type": 99})
    assert ok is False and "unknown cmd_type" in message
    ok, message = r.command({"cmd_type": 3})  # GET_STATE
    assert ok is True and '"received": 0' in message


def test_data_before_init_and_bad_frames_get_data_error(robot):
    r = robot()
    r.frame({"timestamp": 1, "frame": make_jpeg()})
    assert "INIT" in r.next("data_error")["error"]
    r.init()
    bad = [
        ({"frame": make_jpeg()}, "missing 'timestamp'"),
        ({"timestamp": "x", "frame": make_jpeg()}, "must be an integer"),
        ({"timestamp": 2}, "missing 'frame'"),
        ({"timestamp": 3, "frame": "text"}, "must be binary"),
        ({"timestamp": 4, "frame": corrupt_jpeg()}, "corrupt JPEG"),
        ("not a mapping", "expected a mapping"),
    ]
    for message, text in bad:
        r.frame(message)
        error = r.next("data_error")
        assert text in error["error"], (text, error)
    r.frame({"timestamp": 5, "frame": make_jpeg()})  # the session still works
    assert r.next("results")["timestamp"] == 5


def test_a_flood_of_bad_frames_harms_no_other_robot(robot):
    good, bad = robot(), robot()
    good.init()
    bad.init()
    for i in range(50):
        bad.frame({"timestamp": i, "frame": b"\xff\xd8\xffjunk"})
    for ts in range(1, 11):
        good.frame({"timestamp": ts, "frame": make_jpeg()})
        assert good.next("results")["timestamp"] == ts
    # every bad frame is accounted for, each with a data_error: refused, or superseded by a newer one (newest wins)
    deadline = time.monotonic() + 20
    while True:
        state = json.loads(bad.command({"cmd_type": 3})[1])
        if state["rejected"] + state["dropped"] == 50:
            break
        assert time.monotonic() < deadline, state
        threading.Event().wait(0.05)
    reasons = [bad.next("data_error")["reason"] for _ in range(50)]
    assert reasons.count("superseded") == state["dropped"] and reasons.count("bad_frame") == state["rejected"] >= 1


def test_unmodified_era_5g_client_streams_and_gets_results(tiny_server):
    with era_robot(tiny_server.url, robot="era") as (client, got):
        from era_5g_interface.channels import ChannelType

        frame = np.full((96, 128, 3), 90, np.uint8)
        for _ in range(5):
            ts = time.perf_counter_ns()
            client.send_image(frame, "image", ChannelType.JPEG, ts)
            result = got.get(timeout=10)
            assert result["timestamp"] == ts
            assert result["detections"][0]["class_name"] == TINY_NAMES[2]
            hint = result["hint"]  # the extra key (and session_info) it tolerates
            assert hint["input_size"] == [64, 64] and hint["next_frame_in_ms"] >= 0


def test_disconnect_closes_the_session(tiny_server, robot):
    import requests

    r = robot()
    r.init()
    metric = 'netapp_active_sessions{transport="ws"}'
    assert f"{metric} 1.0" in requests.get(f"{tiny_server.url}/metrics", timeout=5).text
    r.close()
    deadline = time.monotonic() + 10
    while f"{metric} 0.0" not in requests.get(f"{tiny_server.url}/metrics", timeout=5).text:
        assert time.monotonic() < deadline, "the session outlived its connection"
        threading.Event().wait(0.05)


def test_a_connection_leaves_no_state_behind(tiny_server, robot):
    """The transport's connection (its decoders among them), the session and its queue go with the robot."""
    app = tiny_server.app.other_asgi_app
    plane, state = app.state.dataplane, app.state.netapp
    r = robot()
    r.init()
    sid = r.sio.eio.sid
    r.frame({"timestamp": 1, "frame": make_jpeg()})
    r.next("results")
    assert plane.connection(sid) is not None and state.sessions.get(sid) is not None
    r.close()
    deadline = time.monotonic() + 10
    while plane.connection(sid) is not None or state.sessions.get(sid) is not None:
        assert time.monotonic() < deadline, "the connection's state outlived it"
        threading.Event().wait(0.05)
    assert state.pipeline.queues() == 0


def test_oversized_frames_get_an_error_or_a_closed_connection_never_a_crash(serve, tiny_detector):
    from netapp.server.settings import Settings

    server = serve(tiny_detector, Settings(max_payload_bytes=50_000))
    big, steady = RawRobot(server.url), RawRobot(server.url)
    try:
        big.init()
        steady.init()
        big.frame({"timestamp": 1, "frame": b"\xff\xd8\xff" + b"\0" * 60_000})
        assert "over the 50000-byte limit" in big.next("data_error")["error"]
        big.frame({"timestamp": 2, "frame": b"\xff\xd8\xff" + b"\0" * 3_000_000})  # past the transport limit
        deadline = time.monotonic() + 10
        while big.sio.connected:
            assert time.monotonic() < deadline, "a message past the transport limit must close that connection"
            threading.Event().wait(0.05)
        for ts in (10, 11, 12):
            steady.frame({"timestamp": ts, "frame": make_jpeg()})
            assert steady.next("results")["timestamp"] == ts
    finally:
        steady.close()
