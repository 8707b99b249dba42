"""Priority classes: who may claim which class (pure), and the scheduler's turns between classes: higher classes
first under overload, the lowest never below its floor, equal classes fair, a robot alone at every turn."""

from __future__ import annotations

from collections import Counter

import pytest

from netapp.protocol import PRIORITY_CLASSES, parse_priority
from netapp.server.errors import RequestRefused
from netapp.server.pipeline.frame import Frame
from netapp.server.pipeline.priorities import DEFAULT_WEIGHTS, floor_shares, parse_weights, robot_priority
from netapp.server.pipeline.scheduling import Scheduler
from netapp.server.sessions import Session

LOW, NORMAL, HIGH = (PRIORITY_CLASSES.index(name) for name in ("low", "normal", "high"))


def test_a_robot_may_lower_its_class_never_raise_it_past_what_its_token_grants():
    assert robot_priority({}, NORMAL) == NORMAL  # no claim: the class its token grants
    assert robot_priority({"priority": "low"}, NORMAL) == LOW
    assert robot_priority({"priority": " High "}, HIGH) == HIGH
    assert robot_priority({"priority": 0}, NORMAL) == LOW
    with pytest.raises(RequestRefused) as above:
        robot_priority({"priority": "high"}, NORMAL)
    assert above.value.status == 403 and above.value.reason == "priority_not_allowed"
    assert "normal at most" in str(above.value) and above.value.details == {"granted": "normal"}
    for bad in ("urgent", 3, -1, True, 1.5, ["high"], {"a": 1}, "x" * 10_000):
        with pytest.raises(RequestRefused) as unknown:
            robot_priority({"priority": bad}, HIGH)
        assert unknown.value.status == 422 and unknown.value.reason == "bad_priority"
        assert "low, normal, high" in str(unknown.value) and len(str(unknown.value)) < 200


def test_parse_priority_takes_names_and_indexes():
    assert [parse_priority(n) for n in PRIORITY_CLASSES] == [0, 1, 2] == [parse_priority(i) for i in range(3)]


class Line:
    """A scheduler with robots that always have a frame waiting (as streaming robots do), one frame per batch."""

    def __init__(  # robots: name -> (class, cost in seconds)
        self, robots: dict[str, tuple[int, float]], weights: tuple[float, ...] = DEFAULT_WEIGHTS
    ) -> None:
        self.scheduler = Scheduler(queue_size=1, drop=lambda session, frame: None, weights=weights)
        self.sessions = {
            name: Session(id=name, transport="ws", robot_id=name, args={}, results_buffer=1, cost_s=cost, priority=c)
            for name, (c, cost) in robots.items()
        }
        self.seq = 0
        self.ran: Counter = Counter()
        self.streaming = set(robots)  # robots whose next frame is queued while one runs
        for session in self.sessions.values():
            self.offer(session)

    def offer(self, session: Session) -> None:
        self.seq += 1
        self.scheduler.submit(session, Frame(timestamp=self.seq, recv_ns=0, seq=self.seq, transport="ws"))

    def turn(self) -> str:
        batch, late = self.scheduler.collect([self.scheduler.take_ready()], 1, 0, 0.0)
        assert late == [] and len(batch) == 1
        session = batch[0][0]
        self.ran[session.id] += 1
        if session.id in self.streaming:
            self.offer(session)  # its next frame, queued while this one runs
        self.scheduler.release(batch)
        return session.id

    def time_share(self, names: list[str]) -> float:
        given = {n: self.ran[n] * s.cost_s for n, s in self.sessions.items()}
        return sum(given[n] for n in names) / sum(given.values())


def test_under_overload_the_high_class_goes_first_and_gets_its_weights_share():
    line = Line({"high": (HIGH, 0.02), **{f"low-{i}": (LOW, 0.02) for i in range(4)}})
    for _ in range(500):
        line.turn()
    # high and low waiting: 4/5 of the time to high, 1/5 to the low class (plain round robin: 1/5 to high)
    assert line.time_share(["high"]) == pytest.approx(0.8, abs=0.02)
    lows = [line.ran[f"low-{i}"] for i in range(4)]
    assert max(lows) - min(lows) <= 1, lows  # the low robots share their class's time evenly


def test_priority_weights_parse_from_the_flags_words_and_say_what_to_write_when_wrong():
    assert parse_weights("low=1,normal=2,high=4") == DEFAULT_WEIGHTS
    assert parse_weights(" HIGH = 9 , low=0.5") == (0.5, 2.0, 9.0)  # a class left out keeps its default
    for bad in ("low=0", "low=-1", "normal=nan", "high=inf", "urgent=3", "low", "low=x", "", "low=1,,high=2", "=1"):
        with pytest.raises(ValueError) as wrong:
            parse_weights(bad)
        message = str(wrong.value)
        assert "--priority-weights takes CLASS=WEIGHT" in message and "low=1,normal=2,high=4" in message
        assert "\n" not in message and len(message) < 200
    assert len(str(pytest.raises(ValueError, parse_weights, "low=" + "9" * 10_000).value)) < 200


def test_weights_from_the_flag_set_the_shares_the_floors_say():
    weights = parse_weights("low=1,high=9")
    assert floor_shares(weights)[HIGH] == pytest.approx(9 / 12)
    line = Line({"high": (HIGH, 0.02), **{f"low-{i}": (LOW, 0.02) for i in range(4)}}, weights)
    for _ in range(500):
        line.turn()
    assert line.time_share(["high"]) == pytest.approx(9 / 10, abs=0.02)  # high and low waiting: 9 to 1


def test_a_high_robot_that_needs_little_runs_at_the_next_turn_whatever_waits():
    line = Line({f"low-{i}": (LOW, 0.02) for i in range(6)})
    for _ in range(50):
        line.turn()
    high = Session(id="high", transport="ws", robot_id="high", args={}, results_buffer=1, cost_s=0.02, priority=HIGH)
    line.sessions["high"] = high
    for _ in range(20):  # a frame now and then (a 5 FPS robot among 25 FPS ones): each runs at the next turn
        line.offer(high)
        assert line.turn() == "high"
        for _ in range(3):
            assert line.turn() != "high"  # it has no frame waiting: the others run meanwhile
        line.ran["high"] += 0


@pytest.mark.parametrize("rounds", [70, 700])
def test_the_lowest_class_gets_at_least_its_floor_and_no_robot_starves(rounds):
    line = Line(
        {
            "high-1": (HIGH, 0.02),
            "high-2": (HIGH, 0.04),  # a heavy high robot
            "normal": (NORMAL, 0.02),
            "low-1": (LOW, 0.02),
            "low-2": (LOW, 0.01),
        }
    )
    for _ in range(rounds):
        line.turn()
    floor = floor_shares(DEFAULT_WEIGHTS)
    assert line.time_share(["low-1", "low-2"]) >= floor[LOW] - 0.02, line.ran
    assert line.time_share(["normal"]) >= floor[NORMAL] - 0.02, line.ran
    assert all(line.ran[name] > 0 for name in line.sessions), line.ran
    # within a class, turns stay weighed by cost: the heavy high robot gets about the other's time, not more
    assert line.time_share(["high-2"]) / line.time_share(["high-1"]) == pytest.approx(1.0, abs=0.25)


def test_equal_classes_stay_fair_and_a_robot_alone_gets_every_turn():
    for c in (LOW, NORMAL, HIGH):
        line = Line({f"r{i}": (c, 0.02) for i in range(3)})
        for _ in range(300):
            line.turn()
        assert line.ran == Counter({"r0": 100, "r1": 100, "r2": 100})
    alone = Line({"low": (LOW, 0.05)})
    assert [alone.turn() for _ in range(10)] == ["low"] * 10


def test_a_class_that_waited_for_nothing_banks_no_time():
    """A high robot idle for a long time then flooding gets its weight's share from then on, not a burst that
    shuts the others out while it spends time it never used."""
    line = Line({"low": (LOW, 0.02)})
    for _ in range(200):
        line.turn()
    high = Session(id="high", transport="ws", robot_id="high", args={}, results_buffer=1, cost_s=0.02, priority=HIGH)
    line.sessions["high"] = high
    line.streaming.add("high")
    line.offer(high)
    turns = [line.turn() for _ in range(50)]
    assert 36 <= turns.count("high") <= 44, Counter(turns)  # 4/5 of the turns from the first one
    assert "low" in turns[:6]
