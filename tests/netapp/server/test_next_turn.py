"""The next-turn estimate (pure): a round of the session's class stretched by its class's share, from its last turn."""

from __future__ import annotations

import pytest

from netapp.server.pipeline.next_turn import MAX_NEXT_TURN_S, next_turn_in_s
from netapp.server.pipeline.priorities import DEFAULT_WEIGHTS

LOW, NORMAL, HIGH = 0, 1, 2


def test_a_robot_alone_may_send_at_once():
    assert next_turn_in_s(NORMAL, 0.02, 0.03, [], DEFAULT_WEIGHTS) == 0.0


def test_robots_of_one_class_take_a_round_of_everyones_cost():
    # 8 robots at 15 ms of netapp time each: 120 ms between one robot's turns; its turn began 30 ms ago
    others = [(NORMAL, 0.015)] * 7
    assert next_turn_in_s(NORMAL, 0.015, 0.030, others, DEFAULT_WEIGHTS) == pytest.approx(0.090)
    heavy = [(NORMAL, 0.045)] + [(NORMAL, 0.015)] * 6  # a heavy robot lengthens everyone's round
    assert next_turn_in_s(NORMAL, 0.015, 0.030, heavy, DEFAULT_WEIGHTS) == pytest.approx(0.120)
    unmeasured = [(NORMAL, 0.0)] * 7  # counted at the session's own cost
    assert next_turn_in_s(NORMAL, 0.015, 0.030, unmeasured, DEFAULT_WEIGHTS) == pytest.approx(0.090)


def test_classes_stretch_the_round_by_their_share():
    others = [(HIGH, 0.02)] + [(LOW, 0.02)] * 3
    high = next_turn_in_s(HIGH, 0.02, 0.0, [(LOW, 0.02)] * 4, DEFAULT_WEIGHTS)
    assert high == pytest.approx(0.02 / (4 / 5))  # high and low waiting: high gets 4/5 of the time
    low = next_turn_in_s(LOW, 0.02, 0.0, others, DEFAULT_WEIGHTS)
    assert low == pytest.approx(4 * 0.02 / (1 / 5))  # the low class's round of four, in its fifth of the time
    assert high < low


def test_the_hint_is_bounded():
    crowd = [(NORMAL, 0.5)] * 60
    assert next_turn_in_s(NORMAL, 0.5, 0.0, crowd, DEFAULT_WEIGHTS) == MAX_NEXT_TURN_S
    assert next_turn_in_s(NORMAL, 0.01, 5.0, [(NORMAL, 0.01)] * 3, DEFAULT_WEIGHTS) == 0.0  # overdue: send now


def test_a_class_gets_what_the_others_leave_and_at_least_its_weights_share():
    others = [(HIGH, 0.02)] + [(LOW, 0.02)] * 3
    # the high robot uses 0.4 of the netapp's time: the low class has 0.6, not its weight's 1/5
    low = next_turn_in_s(LOW, 0.02, 0.0, others, DEFAULT_WEIGHTS, use=[0.6, 0.0, 0.4])
    assert low == pytest.approx(4 * 0.02 / 0.6)
    # a high class that takes all it may: the low class has its floor, 1/5
    assert next_turn_in_s(LOW, 0.02, 0.0, others, DEFAULT_WEIGHTS, use=[0.2, 0.0, 0.8]) == pytest.approx(0.4)
    # the session's own class's use does not count: nothing feeds back on itself
    assert next_turn_in_s(LOW, 0.02, 0.0, others, DEFAULT_WEIGHTS, use=[0.0, 0.0, 0.4]) == pytest.approx(4 * 0.02 / 0.6)
