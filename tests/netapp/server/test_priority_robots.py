"""Priority classes with real robots over a real netapp: under overload a high-priority robot's frames are served
first and the low ones still get results; a class a robot may not have is refused at once, saying why, on HTTP and
Socket.IO; a class token lets its robot claim its class."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest
import requests

from netapp.client import NetAppClient, NetAppError, NetAppRefused
from netapp.protocol import PRIORITY_WEIGHTS_ENV
from netapp.serve_process import free_port
from netapp.server.access import token_digest
from netapp.server.settings import Settings
from tests.support.images import make_jpeg
from tests.support.processors import SlowProcessor
from tests.support.raw_robot import RawRobot

HIGH_TOKEN = "high-class-token"


def settings(**overrides) -> Settings:
    # One lane, decoding on it: every frame waits in the scheduler's lines, where the classes are decided.
    return Settings(lanes=1, prepare_threads=0, priority_tokens={token_digest(HIGH_TOKEN): 2}, **overrides)


def metric(url: str, name: str) -> float:
    for row in requests.get(f"{url}/metrics", timeout=5).text.splitlines():
        if row.startswith(name + " "):
            return float(row.split()[-1])
    raise AssertionError(f"{name} not in /metrics")


def wait_for(condition, what: str, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"not within {timeout_s} s: {what}"
        time.sleep(0.01)  # polling with a deadline


@pytest.mark.parametrize("transport", ["http", "ws", "frames"])
def test_the_high_robots_frame_is_served_first_and_the_low_ones_still_get_results(serve, gated, transport):
    url = serve(gated, settings()).url
    frame = make_jpeg()
    lows = [NetAppClient(url, transport=transport, args={"priority": "low"}, pacing=False) for _ in range(3)]
    high = NetAppClient(url, transport=transport, token=HIGH_TOKEN, args={"priority": "high"}, pacing=False)
    robots = [*lows, high]
    try:
        for robot in robots:
            robot.connect()
        lows[0].send(frame)
        assert gated.entered.acquire(timeout=10)  # its frame holds the inference thread
        for waiting, robot in enumerate([*lows[1:], high], start=1):  # one by one: the high robot's frame last
            robot.send(frame)
            wait_for(lambda n=waiting: metric(url, "netapp_queue_depth") == n, f"{waiting} frames waiting")
        gated.gate.set()
        results = {id(robot): next(robot.results(timeout=10)) for robot in robots}
        started = {id(r): results[id(r)].message["timestamp_before_process"] for r in robots}
        queued_lows = [started[id(r)] for r in lows[1:]]
        assert started[id(high)] < min(queued_lows), started  # first of the frames that waited
        assert all(results[id(r)].detections is not None for r in lows)  # and the low ones were served too
    finally:
        for robot in robots:
            robot.close()


def test_under_overload_a_streaming_high_robot_gets_more_turns_and_no_low_robot_starves(serve):
    slow = SlowProcessor(0.01)
    url = serve(slow, settings()).url
    frame = make_jpeg()
    robots = {
        "high": NetAppClient(url, transport="ws", token=HIGH_TOKEN, max_in_flight=2, pacing=False),
        **{f"low-{i}": NetAppClient(url, transport="ws", args={"priority": "low"}, pacing=False) for i in range(3)},
    }
    try:
        for robot in robots.values():
            robot.connect()  # no claim: the high robot gets what its token grants

        def stream() -> bool:
            for robot in robots.values():
                robot.send(frame)
            return robots["high"].stats.results >= 40

        wait_for(stream, "40 results for the high robot", timeout_s=60)
        served = {name: robot.stats.results for name, robot in robots.items()}
        assert all(served[f"low-{i}"] >= 1 for i in range(3)), served  # the low class keeps its floor
        assert served["high"] > max(served[f"low-{i}"] for i in range(3)), served
    finally:
        for robot in robots.values():
            robot.close()


def test_a_class_a_robot_may_not_have_is_refused_at_once_on_http(serve, gated):
    url = serve(gated, settings()).url
    for args, status, reason in (({"priority": "urgent"}, 422, "bad_priority"), ({"priority": "high"}, 403, None)):
        answer = requests.post(f"{url}/register", json={"args": args}, timeout=5)
        assert answer.status_code == status, answer.text
        assert answer.json()["reason"] == (reason or "priority_not_allowed")
    refused = requests.post(f"{url}/register", json={"args": {"priority": "high"}}, timeout=5).json()
    assert "normal at most" in refused["error"] and refused["granted"] == "normal"
    assert metric(url, 'netapp_frames_rejected_total{reason="priority_not_allowed",transport="http"}') == 2
    assert metric(url, 'netapp_frames_rejected_total{reason="bad_priority",transport="http"}') == 1
    allowed = requests.post(
        f"{url}/register", json={"args": {"priority": "high"}}, headers={"Authorization": f"Bearer {HIGH_TOKEN}"}
    )
    assert allowed.status_code == 201, allowed.text
    with pytest.raises(NetAppError, match="priority must be one of low, normal, high"):
        NetAppClient(url, transport="http", args={"priority": "urgent"}, connect_timeout_s=5).connect()


def test_a_class_a_robot_may_not_have_is_refused_at_once_on_socketio(serve, gated):
    url = serve(gated, settings()).url
    robot = RawRobot(url)
    try:
        ok, message = robot.init(priority="high")
        assert not ok and "normal at most" in message
        error = robot.next("command_error")
        assert error["reason"] == "priority_not_allowed" and error["granted"] == "normal"
        ok, message = robot.init(priority=7)
        assert not ok and "priority must be one of low, normal, high" in message
        assert robot.next("command_error")["reason"] == "bad_priority"
        ok, message = robot.init(priority="low")  # lower than it may: fine
        assert ok, message
    finally:
        robot.close()
    for transport in ("ws", "frames"):
        started = time.monotonic()
        with pytest.raises(NetAppRefused) as refused:
            NetAppClient(url, transport=transport, args={"priority": "high"}, connect_timeout_s=10).connect()
        assert refused.value.reason == "priority_not_allowed" and "normal at most" in str(refused.value)
        assert time.monotonic() - started < 5  # at once, not after the connect timeout
        with NetAppClient(url, transport=transport, token=HIGH_TOKEN, args={"priority": "high"}) as high:
            assert high.session_id  # the class token lets it claim high


@pytest.mark.parametrize("given", ["flag", "env"])
def test_netapp_serve_refuses_priority_weights_it_cannot_use_in_one_line(tiny_model_path, given):
    """`--priority-weights` (or NETAPP_PRIORITY_WEIGHTS, its default): a wrong value stops the netapp at start with
    one line saying what to write, before the model loads."""
    argv = [sys.executable, "-m", "netapp", "serve", "--model", str(tiny_model_path), "--port", str(free_port())]
    env = {k: v for k, v in os.environ.items() if k != PRIORITY_WEIGHTS_ENV}
    if given == "flag":
        argv += ["--priority-weights", "low=1,urgent=8"]
    else:
        env[PRIORITY_WEIGHTS_ENV] = "low=0"
    done = subprocess.run(argv, capture_output=True, text=True, timeout=60, env=env)
    assert done.returncode == 2, done.stderr
    errors = [line for line in done.stderr.splitlines() if "--priority-weights" in line]
    assert len(errors) == 1 and "e.g. low=1,normal=2,high=4" in errors[0], done.stderr
