"""Retry-After from what the netapp measures (`netapp.server.retry_after`): the pure rules, the session registry's
measured lifetimes, and real netapps whose refusals for load (sessions full, too many waiting) carry a Retry-After
that follows the load, the same on HTTP (header and body), Socket.IO (`command_error`) and 5G-ERA (the ack)."""

from __future__ import annotations

import math
import queue
import threading
import time

import pytest
import requests
import socketio

from netapp.protocol import (
    COMMAND_ERROR_EVENT,
    COMMAND_EVENT,
    CONTROL_NAMESPACE,
    DATA_NAMESPACE,
    MAX_RETRY_AFTER_S,
    CommandType,
)
from netapp.server.errors import SessionsFull
from netapp.server.retry_after import (
    MIN_RETRY_AFTER_S,
    SESSIONS_FULL_RETRY_S,
    bounded,
    queue_retry_after_s,
    sessions_retry_after_s,
)
from netapp.server.sessions import SessionRegistry
from netapp.server.settings import Settings
from tests.support.images import make_jpeg
from tests.support.processors import GatedProcessor


def test_a_queue_takes_its_frames_over_the_capacity_to_work_through():
    assert queue_retry_after_s(40, 10.0) == 4
    assert queue_retry_after_s(41, 10.0) == 5  # whole seconds, rounded up: sooner would be refused again
    assert queue_retry_after_s(64, 8.0) > queue_retry_after_s(16, 8.0) > queue_retry_after_s(16, 32.0)
    assert queue_retry_after_s(0, 10.0) == MIN_RETRY_AFTER_S
    assert queue_retry_after_s(10_000, 0.5) == MAX_RETRY_AFTER_S
    for unmeasured in (None, 0.0, -1.0, math.nan):
        assert queue_retry_after_s(50, unmeasured) == MIN_RETRY_AFTER_S  # as before anything was measured


def test_sessions_full_waits_for_the_first_of_the_live_sessions_to_end():
    assert sessions_retry_after_s(4, None) == SESSIONS_FULL_RETRY_S == 5  # nothing ended yet: as before
    assert sessions_retry_after_s(4, 20.0) == 5 and sessions_retry_after_s(10, 20.0) == 2
    assert sessions_retry_after_s(2, 0.01) == MIN_RETRY_AFTER_S
    assert sessions_retry_after_s(1, 3600.0) == MAX_RETRY_AFTER_S  # robots that stay: ask elsewhere, not here
    assert sessions_retry_after_s(0, 7.0) == 7
    for value in (-5.0, 0.0, 0.2, 1e300, math.inf, math.nan):
        assert MIN_RETRY_AFTER_S <= bounded(value) <= MAX_RETRY_AFTER_S


def test_the_registry_measures_how_long_sessions_last_and_a_full_one_says_when_to_retry():
    sessions = SessionRegistry(1, limit=lambda: (2, "its session cap"))
    first, _ = sessions.create("ws"), sessions.create("ws")
    with pytest.raises(SessionsFull) as full:
        sessions.create("ws")
    assert full.value.retry_after_s == 5 and "retry in 5 s" in str(full.value)
    first.opened_s -= 24.0  # it lasted 24 s
    sessions.remove(first.id)
    sessions.create("ws")
    with pytest.raises(SessionsFull) as full:
        sessions.create("ws")
    assert full.value.retry_after_s == 13  # 24 s over the 2 live sessions, rounded up
    assert "retry in 13 s" in str(full.value)
    record = sessions.create("http", admit=False)  # a token admitted elsewhere: its end says nothing of here
    record.opened_s -= 1000.0
    sessions.remove(record.id)
    assert sessions.mean_lifetime_s == pytest.approx(24.0, abs=1.0)


def register(url: str) -> requests.Response:
    return requests.post(f"{url}/register", json={}, timeout=10)


def init_refused(url: str) -> tuple[dict, tuple]:
    """A Socket.IO robot's INIT on a full netapp: its command_error and its 5G-ERA acknowledgement."""
    errors: queue.Queue = queue.Queue()
    client = socketio.Client()
    client.on(COMMAND_ERROR_EVENT, errors.put, namespace=CONTROL_NAMESPACE)
    client.connect(url, namespaces=[DATA_NAMESPACE, CONTROL_NAMESPACE], transports=["websocket"], wait_timeout=10)
    try:
        ack = client.call(COMMAND_EVENT, {"cmd_type": CommandType.INIT, "data": {}}, namespace=CONTROL_NAMESPACE)
        return errors.get(timeout=10), tuple(ack)
    finally:
        client.disconnect()


def test_a_full_netapp_says_on_every_transport_when_its_next_session_should_free(serve):
    server = serve(GatedProcessor(), Settings(lanes=1, max_sessions=2))
    started = time.monotonic()
    first = register(server.url).json()["session_id"]
    assert register(server.url).status_code == 201
    refused = register(server.url)
    assert refused.status_code == 503 and refused.headers["Retry-After"] == "5"  # no session has ended yet
    assert refused.json()["retry_after_s"] == 5 and refused.json()["reason"] == "sessions_full"

    assert requests.post(f"{server.url}/unregister", headers={"X-Session-Id": first}, timeout=10).ok
    lasted_at_most = time.monotonic() - started
    assert register(server.url).status_code == 201  # full again
    refused = register(server.url)
    retry = int(refused.headers["Retry-After"])
    # the one session that ended lasted less than this test so far: the next of the two is expected sooner
    assert MIN_RETRY_AFTER_S <= retry <= max(MIN_RETRY_AFTER_S, math.ceil(lasted_at_most / 2)) < 5
    assert refused.json()["retry_after_s"] == retry
    error, ack = init_refused(server.url)
    assert error["reason"] == "sessions_full" and error["retry_after_s"] == retry
    assert ack[0] is False and f"retry in {retry} s" in ack[1]  # what an unmodified 5G-ERA robot reads


def capacity_fps(url: str) -> float:
    return requests.get(f"{url}/capacity", timeout=10).json()["capacity_fps"]


def queue_depth(url: str) -> float:
    text = requests.get(f"{url}/metrics", timeout=10).text
    return next(float(line.split()[-1]) for line in text.splitlines() if line.startswith("netapp_queue_depth "))


class Metered(GatedProcessor):
    """Takes `seconds` per batch once its gate is open (the gate holds the queue while a test fills it)."""

    name = "metered"

    def __init__(self, seconds: float) -> None:
        super().__init__()
        self.seconds = seconds
        self.gate.set()

    def process(self, batch):
        results = super().process(batch)
        time.sleep(self.seconds)  # the cost of inference, not synchronisation
        return results


@pytest.mark.parametrize("seconds", [0.02, 0.2])
def test_too_many_waiting_says_how_long_the_queue_takes_at_the_measured_capacity(serve, seconds):
    waiting = 6
    processor = Metered(seconds)
    server = serve(processor, Settings(lanes=1, prepare_threads=0, max_waiting=waiting, warm_batches=1))
    tokens = [register(server.url).json()["session_id"] for _ in range(waiting + 1)]

    def send(token: str) -> requests.Response:
        headers = {"X-Session-Id": token, "X-Timestamp": "1", "Content-Type": "image/jpeg"}
        return requests.post(f"{server.url}/send_image?wait=true", data=make_jpeg(), headers=headers, timeout=30)

    for _ in range(3):  # measured: a few batches at the processor's cost
        assert send(tokens[0]).status_code == 200
    measured = capacity_fps(server.url)
    assert measured is not None and measured <= 1 / seconds
    processor.gate.clear()  # the queue fills: one frame held in process, the rest waiting for it
    answers: list[requests.Response] = []
    senders = [threading.Thread(target=lambda t=t: answers.append(send(t))) for t in tokens[:waiting]]
    for sender in senders:
        sender.start()
    deadline = time.monotonic() + 20
    while queue_depth(server.url) < waiting - 1:  # polling with a deadline
        assert time.monotonic() < deadline, "the waiting requests never queued"
        time.sleep(0.02)
    refused = send(tokens[waiting])
    processor.gate.set()
    for sender in senders:
        sender.join(30)
    assert refused.status_code == 503 and refused.json()["reason"] == "too_many_waiting", refused.text
    retry = int(refused.headers["Retry-After"])
    assert refused.json()["retry_after_s"] == retry
    # the frames waiting over the capacity measured while they queued (no batch ended meanwhile: the gate held it)
    assert retry == max(1, math.ceil(waiting / measured))
    assert all(answer.status_code == 200 for answer in answers)
    if seconds == 0.2:
        assert retry >= 2  # 6 frames at 0.2 s each or more: longer than a fixed second
