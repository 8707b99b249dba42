"""Deadlines on the netapp: a frame that cannot finish within its robot's deadline is dropped before inference,
the robot hears why (HTTP 504 / data_error / polled results, reason `deadline`), and it is counted apart from
newest-wins drops. Old robots send no deadline and see no change."""

from __future__ import annotations

import threading
import time

import pytest
import requests

from netapp.protocol import DEADLINE_HEADER, DEADLINE_REASON, parse_deadline_ms
from tests.support.images import make_jpeg
from tests.support.processors import SlowProcessor
from tests.support.raw_robot import RawRobot


def register(url: str) -> str:
    return requests.post(f"{url}/register", timeout=5).json()["session_id"]


def send(url: str, sid: str, deadline_ms=None, wait: bool = True, timestamp: int = 1) -> requests.Response:
    headers = {"X-Session-Id": sid, "Content-Type": "image/jpeg", "X-Timestamp": str(timestamp)}
    if deadline_ms is not None:
        headers[DEADLINE_HEADER] = str(deadline_ms)
    return requests.post(
        f"{url}/send_image", params={"wait": str(wait).lower()}, data=make_jpeg(), headers=headers, timeout=10
    )


def metric(url: str, line: str) -> float:
    for row in requests.get(f"{url}/metrics", timeout=5).text.splitlines():
        if row.startswith(line + " "):
            return float(row.split()[-1])
    raise AssertionError(f"{line} not in /metrics")


def test_parse_deadline_ms() -> None:
    assert parse_deadline_ms(None) is None
    assert parse_deadline_ms(200) == 200.0 and parse_deadline_ms("150.5") == 150.5
    for bad in (0, -5, "soon", True, 1e9, [200], "nan"):
        with pytest.raises(ValueError, match="deadline_ms"):
            parse_deadline_ms(bad)


def test_http_frame_that_cannot_make_its_deadline_is_dropped_before_inference(serve) -> None:
    slow = SlowProcessor(0.2)
    url = serve(slow).url
    sid = register(url)
    assert send(url, sid).status_code == 200  # no deadline: processed, and the netapp now knows it takes ~200 ms
    assert slow.calls == 1

    late = send(url, sid, deadline_ms=50, timestamp=2)
    assert late.status_code == 504, late.text
    body = late.json()
    assert body["reason"] == DEADLINE_REASON and body["timestamp"] == 2
    assert "50 ms deadline" in body["error"] and "processing takes about" in body["error"]
    assert slow.calls == 1  # no inference was spent on it

    assert send(url, sid, deadline_ms=5000, timestamp=3).status_code == 200  # a deadline it can meet
    assert slow.calls == 2
    assert metric(url, 'netapp_frames_deadline_dropped_total{transport="http"}') == 1
    assert metric(url, 'netapp_frames_dropped_total{transport="http"}') == 0  # apart from newest-wins drops
    stats = requests.post(f"{url}/unregister", headers={"X-Session-Id": sid}, timeout=5).json()
    assert (stats["processed"], stats["deadline_dropped"], stats["dropped"], stats["rejected"]) == (2, 1, 0, 0)


def test_a_frame_that_waited_past_its_deadline_is_dropped(serve, gated) -> None:
    # No measurement is needed when the deadline has already passed in the queue.
    url = serve(gated).url
    sid = register(url)
    first = threading.Thread(target=send, args=(url, sid))
    first.start()
    assert gated.entered.acquire(timeout=10)  # frame 1 holds the inference thread
    queued = []
    second = threading.Thread(target=lambda: queued.append(send(url, sid, deadline_ms=100, timestamp=2)))
    second.start()
    deadline = time.monotonic() + 10
    while metric(url, 'netapp_frames_received_total{transport="http"}') < 2 and time.monotonic() < deadline:
        time.sleep(0.01)  # poll until frame 2 is queued
    time.sleep(0.15)  # let frame 2's 100 ms deadline pass while it waits: the condition under test is time
    gated.gate.set()
    first.join(timeout=10)
    second.join(timeout=10)
    assert queued[0].status_code == 504 and queued[0].json()["reason"] == DEADLINE_REASON
    assert gated.calls == 1


def test_polling_robot_finds_the_deadline_drop_among_its_results(serve) -> None:
    slow = SlowProcessor(0.2)
    url = serve(slow).url
    sid = register(url)
    assert send(url, sid).status_code == 200
    assert send(url, sid, deadline_ms=20, wait=False, timestamp=9).status_code == 202
    deadline = time.monotonic() + 10
    polled: list = []
    while not polled and time.monotonic() < deadline:
        polled = requests.get(f"{url}/results", headers={"X-Session-Id": sid}, timeout=5).json()["results"]
        time.sleep(0.02)  # poll with a deadline
    assert [(p["timestamp"], p["reason"]) for p in polled] == [(9, DEADLINE_REASON)]


def test_bad_deadline_is_refused_and_counted(serve, tiny_detector) -> None:
    url = serve(tiny_detector).url
    sid = register(url)
    for bad in ("soon", "-5", "0", "1e9"):
        r = send(url, sid, deadline_ms=bad)
        assert r.status_code == 422 and r.json()["reason"] == "bad_deadline", r.text
        assert DEADLINE_HEADER in r.json()["error"]
    assert metric(url, 'netapp_frames_rejected_total{reason="bad_deadline",transport="http"}') == 4
    assert send(url, sid, deadline_ms=10_000).status_code == 200  # the session still works


def test_socketio_frame_with_a_deadline_gets_a_data_error(serve) -> None:
    slow = SlowProcessor(0.2)
    url = serve(slow).url
    robot = RawRobot(url)
    try:
        assert robot.init()[0] is True
        robot.frame({"timestamp": 1, "frame": make_jpeg()})  # an old robot's frame: no deadline
        assert robot.next("results")["timestamp"] == 1
        robot.frame({"timestamp": 2, "frame": make_jpeg(), "deadline_ms": 30})
        error = robot.next("data_error")
        assert (error["timestamp"], error["reason"]) == (2, DEADLINE_REASON)
        robot.frame({"timestamp": 3, "frame": make_jpeg(), "deadline_ms": "never"})
        error = robot.next("data_error")
        assert (error["timestamp"], error["reason"]) == (3, "bad_deadline")
        robot.frame({"timestamp": 4, "frame": make_jpeg(), "deadline_ms": 10_000})
        assert robot.next("results")["timestamp"] == 4
        assert slow.calls == 2
        assert metric(url, 'netapp_frames_deadline_dropped_total{transport="ws"}') == 1
    finally:
        robot.close()


def test_a_stale_estimate_is_measured_again(serve) -> None:
    # One slow batch long ago must not drop every frame forever: after a second without a measurement the netapp
    # processes a frame again, and meets the deadline once it is fast again.
    slow = SlowProcessor(0.3)
    url = serve(slow).url
    sid = register(url)
    assert send(url, sid).status_code == 200
    slow.seconds = 0.0
    assert send(url, sid, deadline_ms=100, timestamp=2).status_code == 504
    time.sleep(1.1)  # past the estimate's one-second life: the condition under test is time
    assert send(url, sid, deadline_ms=100, timestamp=3).status_code == 200
    assert send(url, sid, deadline_ms=100, timestamp=4).status_code == 200
