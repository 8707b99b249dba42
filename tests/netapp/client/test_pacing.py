"""The robot's pacer (netapp.client.pacing): its rules, and what it does to many robots sharing one netapp, in a
discrete-event simulation of the netapp's queue (round robin, one-frame queue per robot, newest wins)."""

from __future__ import annotations

import heapq
import itertools
import statistics
import time
from dataclasses import dataclass, field

import pytest

from netapp.client import NetAppClient
from netapp.client.pacing import CALM_RESULTS, MAX_DELAY_NS, Pacer
from netapp.sdk import Processor
from netapp.server.pipeline.next_turn import next_turn_in_s
from netapp.server.pipeline.priorities import DEFAULT_WEIGHTS as WEIGHTS
from netapp.server.settings import Settings
from tests.support.images import make_jpeg

MS = 1_000_000


def test_a_new_pacer_lets_max_in_flight_frames_go_at_once():
    pacer = Pacer(2)
    assert pacer.allows(0, 0) and pacer.allows(1, 0) and not pacer.allows(2, 0)
    assert pacer.wait_ns(0) == 0


def test_a_long_wait_at_the_netapp_closes_the_window_and_holds_the_next_frame_back():
    pacer = Pacer(2)
    pacer.on_result(now_ns=100 * MS, queued_ns=60 * MS, batch_ns=10 * MS)  # 40 ms over the 2-batch target
    assert pacer.window == 1
    assert pacer.delay_ns == 20 * MS  # gain 0.5 of the excess
    assert not pacer.allows(0, 119 * MS) and pacer.wait_ns(119 * MS) == 1 * MS
    assert pacer.allows(0, 120 * MS) and not pacer.allows(1, 120 * MS)
    pacer.on_result(now_ns=200 * MS, queued_ns=40 * MS, batch_ns=10 * MS)  # 20 ms over: from this result alone
    assert pacer.delay_ns == 10 * MS and pacer.window == 1
    assert pacer.not_before_ns == 210 * MS


def test_short_waits_end_the_hold_then_reopen_the_window_one_frame_at_a_time():
    pacer = Pacer(3, window=1, delay_ns=6 * MS)
    pacer.on_result(now_ns=0, queued_ns=2 * MS, batch_ns=10 * MS)  # under the target: no hold
    assert pacer.delay_ns == 0 and pacer.window == 2
    pacer.on_result(now_ns=0, queued_ns=2 * MS, batch_ns=10 * MS)
    assert pacer.window == 3
    pacer.on_result(now_ns=0, queued_ns=2 * MS, batch_ns=10 * MS)
    assert pacer.window == 3  # never past max_in_flight


def test_a_wait_behind_other_robots_keeps_the_window_at_one_even_under_the_target():
    pacer = Pacer(2, window=1)
    pacer.on_result(now_ns=0, queued_ns=15 * MS, batch_ns=10 * MS)  # under 2 batches, but others were ahead
    assert pacer.delay_ns == 0 and pacer.window == 1


def test_a_superseded_frame_closes_the_window_and_reset_forgets_everything():
    pacer = Pacer(2)
    pacer.on_superseded()
    assert pacer.window == 1
    for _ in range(CALM_RESULTS):  # the netapp had no room for two: the window stays closed a while
        pacer.on_result(now_ns=0, queued_ns=0, batch_ns=10 * MS)
        assert pacer.window == 1
    pacer.on_result(now_ns=0, queued_ns=0, batch_ns=10 * MS)
    assert pacer.window == 2
    pacer.on_result(now_ns=0, queued_ns=10_000 * MS, batch_ns=1 * MS)
    assert pacer.delay_ns == MAX_DELAY_NS  # a netapp reporting nonsense cannot stop the robot for longer
    pacer.reset()
    assert (pacer.window, pacer.delay_ns, pacer.not_before_ns, pacer.calm) == (2, 0, 0, 0)


# -- many robots, one netapp -----------------------------------------------------------------------------------


@dataclass
class Robot:
    pacer: Pacer
    pending: int | None = None  # capture time of the newest frame not sent yet
    in_flight: int = 0
    results: list[int] = field(default_factory=list)  # latency of each result (capture to result), ns
    sent: int = 0


@dataclass
class Outcome:
    busy: float  # the netapp's share of time spent on batches
    superseded: int
    sent: int
    results: list[int]  # per robot
    latency_ms: float  # median, capture to result


def simulate(
    robots: int,
    pacing: bool,
    max_in_flight: int = 2,
    batch_ms: float = 16,
    period_ms: float = 40,
    seconds: float = 20,
    hint: bool = False,
) -> Outcome:
    """Robots with cameras at `period_ms` and a NetAppClient's rules (newest frame waits, window, pacer), 1 ms of
    link each way, and a netapp that serves one frame per `batch_ms` in turn (2 ms of decoding counted as queue,
    as the real netapp counts it), keeping one frame per robot (a newer one supersedes it). With `hint`, each result
    says when the robot's next turn comes, as the netapp estimates it (`next_turn_in_s`: a round of every robot's
    cost from its turn's start)."""
    link, prepare, batch = 1 * MS, 2 * MS, int(batch_ms * MS)
    end, warm_up = int(seconds * 1e9), int(seconds * 1e9) // 4
    fleet = [Robot(Pacer(max_in_flight)) for _ in range(robots)]
    if not pacing:
        for r in fleet:  # the pacer's rules off: a fixed window, nothing held back
            r.pacer.on_result = lambda *a: None  # type: ignore[method-assign]
            r.pacer.on_superseded = lambda: None  # type: ignore[method-assign]
    events: list[tuple[int, int, str, int, int]] = []
    order = itertools.count()

    def at(t: int, kind: str, robot: int, value: int = 0) -> None:
        heapq.heappush(events, (t, next(order), kind, robot, value))

    hints: dict[int, float] = {}
    others = [(1, (prepare + batch) / 1e9)] * (robots - 1)
    waiting: dict[int, tuple[int, int]] = {}  # at the netapp, per robot: (arrival, capture)
    turns: list[int] = []  # robots whose frame waits, in arrival order (round robin)
    busy_until, busy_ns, superseded = 0, 0, 0

    def try_send(i: int, now: int) -> None:
        r = fleet[i]
        if r.pending is None:
            return
        if r.pacer.allows(r.in_flight, now):
            r.in_flight += 1
            r.sent += 1
            at(now + link, "arrive", i, r.pending)
            r.pending = None
        elif r.in_flight < r.pacer.window:
            at(now + r.pacer.wait_ns(now), "wake", i)

    def serve(now: int) -> None:
        nonlocal busy_until, busy_ns
        if busy_until > now or not turns:
            return
        i = turns.pop(0)
        arrival, capture = waiting.pop(i)
        start = now + prepare
        busy_until = start + batch
        if now >= warm_up:
            busy_ns += busy_until - now
        at(busy_until + link, "result", i, capture)
        at(busy_until, "idle", i, start - arrival)  # value: the queue wait the result reports
        if hint:  # sent with the result: the next turn, from now on
            hints[i] = 1e9 * next_turn_in_s(1, (prepare + batch) / 1e9, (busy_until - now) / 1e9, others, WEIGHTS)

    for i in range(robots):
        at(i * MS, "camera", i)
    reported: dict[int, int] = {}
    while events:
        now, _, kind, i, value = heapq.heappop(events)
        if now > end:
            break
        r = fleet[i]
        if kind == "camera":
            r.pending = now
            try_send(i, now)
            at(now + int(period_ms * MS), "camera", i)
        elif kind == "wake":
            try_send(i, now)
        elif kind == "arrive":
            if i in waiting:  # newest wins at the netapp: the older frame is superseded, its robot told
                superseded += now >= warm_up
                at(now + link, "superseded", i)
            else:
                turns.append(i)
            waiting[i] = (now, value)
            serve(now)
        elif kind == "idle":
            reported[i] = value
            serve(now)
        elif kind == "result":
            r.in_flight -= 1
            if now >= warm_up:
                r.results.append(now - value)
            r.pacer.on_result(now, reported.pop(i), batch, hints.pop(i, None), 2 * link)
            try_send(i, now)
        elif kind == "superseded":
            r.in_flight -= 1
            r.pacer.on_superseded()
            try_send(i, now)
    return Outcome(
        busy=busy_ns / (end - warm_up),
        superseded=superseded,
        sent=sum(r.sent for r in fleet),
        results=[len(r.results) for r in fleet],
        latency_ms=statistics.median(v for r in fleet for v in r.results) / MS,
    )


@pytest.mark.parametrize("robots", [4, 8, 16])
def test_paced_robots_keep_the_netapp_busy_send_nothing_in_vain_and_get_fresh_results(robots):
    paced = simulate(robots, pacing=True)
    unpaced = simulate(robots, pacing=False)
    one_at_a_time = simulate(robots, pacing=False, max_in_flight=1)
    assert paced.busy > 0.97 and one_at_a_time.busy > 0.97
    assert paced.superseded == 0 < unpaced.superseded  # unpaced robots send frames the netapp throws away
    assert unpaced.superseded > sum(unpaced.results) / 2
    assert min(paced.results) >= 0.95 * max(paced.results)  # fair shares
    # Fresher than one frame at a time: the frame is picked shortly before its turn, not queued behind every other
    # robot's (unpaced robots' results are fresher still, paid for with the frames thrown away).
    assert paced.latency_ms < 0.95 * one_at_a_time.latency_ms


@pytest.mark.parametrize("robots", [4, 8, 16])
def test_with_the_next_turn_hint_frames_arrive_just_before_their_turn(robots):
    guessed = simulate(robots, pacing=True)
    hinted = simulate(robots, pacing=True, hint=True)
    assert hinted.busy > 0.97 and hinted.superseded == 0
    assert min(hinted.results) >= 0.95 * max(hinted.results)  # as fair
    assert sum(hinted.results) >= 0.98 * sum(guessed.results)  # as many results
    assert hinted.latency_ms < 0.85 * guessed.latency_ms, (hinted.latency_ms, guessed.latency_ms)


def test_the_hint_sets_the_hold_and_a_missing_one_leaves_the_guess():
    pacer = Pacer(2)
    pacer.on_result(now_ns=0, queued_ns=60 * MS, batch_ns=10 * MS, next_turn_ns=50 * MS, link_ns=4 * MS)
    assert pacer.delay_ns == 36 * MS and pacer.window == 1  # to arrive a batch before its turn
    pacer.on_result(now_ns=0, queued_ns=60 * MS, batch_ns=10 * MS, next_turn_ns=5 * MS, link_ns=4 * MS)
    assert pacer.delay_ns == 0  # its turn is near: at once
    pacer.on_result(now_ns=0, queued_ns=60 * MS, batch_ns=10 * MS, next_turn_ns=None)
    assert pacer.delay_ns == 20 * MS  # no hint: half the excess wait, as before
    pacer.on_result(now_ns=0, queued_ns=0, batch_ns=10 * MS, next_turn_ns=1e12)
    assert pacer.delay_ns == MAX_DELAY_NS


def test_a_robot_alone_keeps_its_whole_window():
    """One robot and a netapp with time to spare: the window stays open (it hides the link's round trip)."""
    alone = simulate(1, pacing=True, batch_ms=30, period_ms=20)
    assert alone.superseded == 0
    assert alone.busy > 0.97  # two frames in flight keep the netapp busy although the robot waits for results


# -- real robots, a real netapp ----------------------------------------------------------------------------------


class Slow(Processor):
    """About 30 results per second, one frame per batch: three fast robots make it the bottleneck."""

    name = "slow"
    max_batch = 1

    def prepare(self, image, args):
        return image.shape

    def process(self, batch):
        time.sleep(0.03)  # the cost of inference
        return [{"shape": list(shape)} for shape in batch]


def stream_until(clients: list[NetAppClient], results: int, frame: bytes) -> None:
    """Each client sends a frame every 5 ms (a camera faster than the netapp) until each has `results` results."""
    deadline = time.monotonic() + 60
    while any(c.stats.results < results for c in clients):
        assert time.monotonic() < deadline, [c.stats.summary(1.0) for c in clients]
        for client in clients:
            client.send(frame)
        time.sleep(0.005)  # the camera's period, not synchronisation


@pytest.mark.parametrize("transport", ["ws", "http", "frames"])
def test_paced_robots_send_the_netapp_one_frame_per_result(serve, transport):
    """Three robots far faster than the netapp: paced, they send about one frame per result (the netapp supersedes
    none but the first window's); with pacing off, the netapp supersedes most of what they send."""
    server = serve(Slow(), Settings(lanes=2))  # as `netapp serve` runs on 2 cores
    frame = make_jpeg()
    paced = [NetAppClient(server.url, transport, pacing=True).connect() for _ in range(3)]
    try:
        stream_until(paced, 25, frame)
        assert all(c.wait_idle(10) for c in paced)
    finally:
        for client in paced:
            client.close()
    for client in paced:
        stats = client.stats
        assert stats.errors == 0 and stats.lost == 0
        assert stats.dropped_server <= 3, stats.summary(1.0)  # only while the first results were on their way
        assert stats.sent == stats.results + stats.dropped_server
    unpaced = [NetAppClient(server.url, transport, pacing=False).connect() for _ in range(3)]
    try:
        stream_until(unpaced, 25, frame)
    finally:
        for client in unpaced:
            client.close()
    assert sum(c.stats.dropped_server for c in unpaced) > sum(c.stats.results for c in unpaced) / 2
