"""The next-turn hint: every result says when the netapp takes the robot's next frame, and paced robots that follow it
have their frames wait less at the netapp (its own measure of the queue wait). Its bounds: test_hints.py."""

from __future__ import annotations

import statistics
import threading
import time

from netapp.client import NetAppClient
from netapp.server.settings import Settings
from tests.support.images import make_jpeg
from tests.support.processors import SlowProcessor

WARM_UP = 30  # results per robot before its pacer has settled (a window of two at first, a superseded frame)


def queue_waits(url: str, robots: int, results: int) -> tuple[list[float], list[dict]]:
    """Paced robots streaming faster than the netapp until each has `results` results: the netapp's queue wait (ms)
    of each frame after the warm-up, and every result's message."""
    waits: list[float] = []
    messages: list[dict] = []
    lock = threading.Lock()

    def on_result(result) -> None:
        stamps = result.message
        with lock:
            messages.append(stamps)
            wait_ms = (stamps["timestamp_before_process"] - stamps["recv_timestamp"]) / 1e6
            waits.append(wait_ms)

    clients = [NetAppClient(url, transport="ws", on_result=on_result).connect() for _ in range(robots)]
    frame = make_jpeg()
    deadline = time.monotonic() + 60
    try:
        while any(c.stats.results < results for c in clients):
            assert time.monotonic() < deadline, [c.stats.results for c in clients]
            for client in clients:
                client.send(frame)
            time.sleep(0.005)  # a camera far faster than the netapp: its period, not synchronisation
    finally:
        for client in clients:
            client.close()
    return waits[WARM_UP * robots :], messages


def test_with_the_hint_paced_frames_arrive_near_their_turn(serve):
    """Four paced robots on a netapp that takes 20 ms a frame (one lane): with the hint their frames wait about a
    batch; without it, the excess-wait guess leaves them waiting a good part of the round (80 ms)."""
    waits = {}
    for hint in (False, True):
        server = serve(SlowProcessor(0.02), Settings(lanes=1, prepare_threads=0, next_turn_hint=hint))
        waits[hint], messages = queue_waits(server.url, robots=4, results=60)
        hints = [m.get("hint") for m in messages]
        if hint:
            assert all(0 <= h["next_frame_in_ms"] <= 1000 for h in hints), hints[:5]
            assert statistics.median(h["next_frame_in_ms"] for h in hints) > 20  # a round of four, less its turn
        else:
            assert hints == [None] * len(hints)
    guessed, hinted = statistics.median(waits[False]), statistics.median(waits[True])
    assert hinted < 0.7 * guessed, (hinted, guessed)


def test_a_robot_alone_is_told_to_send_at_once(serve):
    """Its round is its own turn: the hint is what is left of that turn's measured cost, a few ms at most."""
    server = serve(SlowProcessor(0.05), Settings(lanes=1, prepare_threads=0))
    _, messages = queue_waits(server.url, robots=1, results=8)
    hints = [m["hint"]["next_frame_in_ms"] for m in messages[1:]]
    assert statistics.median(hints) < 25, hints  # within half a batch (50 ms): plainly not a round of others
