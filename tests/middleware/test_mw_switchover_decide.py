"""The switchover decision (pure): over budget long enough, not too soon after the last move, and only to a
placement that would do better."""

from __future__ import annotations

import math

import pytest
from netapp_middleware.switchover.decision import (
    MOVED,
    STAY_DWELL,
    STAY_NO_BETTER,
    STAY_OK,
    STAY_SUSTAIN,
    Report,
    SwitchPolicy,
    decide,
    over_since,
    sustain_for,
)

POLICY = SwitchPolicy(sustain_s=2.0, recover_ratio=0.8, min_dwell_s=10.0, margin=0.8, memory_s=60.0)
EDGE_CLOUD = ["edge", "cloud"]


def on_edge(*p95s: float | None, start: float = 100.0, budget: float = 100.0, missed: int = 0) -> list[Report]:
    """One report a second on edge from `start`."""
    return [Report(start + i, "edge", p, budget, missed) for i, p in enumerate(p95s)]


def decide_now(
    reports: list[Report],
    measured: dict[str, Report] | None = None,
    arrived_at: float = 0.0,
    warm: tuple[str, ...] = (),
    policy: SwitchPolicy = POLICY,
):
    return decide(reports[-1].at, "edge", arrived_at, reports, measured or {}, EDGE_CLOUD, policy, warm)


def test_within_budget_stays() -> None:
    assert decide_now(on_edge(50, 60, 99)).reason == STAY_OK


def test_over_budget_moves_only_once_it_lasted_sustain_s() -> None:
    assert decide_now(on_edge(50, 150, 160)).reason == STAY_SUSTAIN  # over for 1 s
    decision = decide_now(on_edge(50, 150, 160, 170))  # over for 2 s
    assert (decision.move_to, decision.reason) == ("cloud", MOVED)
    assert "p95 170 ms over the 100 ms budget on edge for 2.0 s" in decision.message


def test_hysteresis_a_dip_just_under_budget_does_not_end_the_streak_a_real_recovery_does() -> None:
    assert over_since(on_edge(150, 90, 150), POLICY) == 100.0  # 90 is within 80%..100% of the budget
    assert decide_now(on_edge(150, 90, 150)).move_to == "cloud"
    assert over_since(on_edge(150, 70, 150), POLICY) == 102.0  # 70 < 80: the streak began again
    assert decide_now(on_edge(150, 70, 150)).reason == STAY_SUSTAIN
    assert over_since(on_edge(150, 70), POLICY) is None


def test_no_move_sooner_than_the_minimum_dwell_time() -> None:
    reports = on_edge(150, 150, 150)
    assert decide_now(reports, arrived_at=95.0).reason == STAY_DWELL  # arrived 7 s ago
    assert decide_now(reports, arrived_at=92.0).move_to == "cloud"  # 10 s ago


def test_no_move_when_no_placement_would_do_better() -> None:
    cloud_was_slow = {"cloud": Report(90.0, "cloud", 140.0, 100.0)}  # under today's 150, but over budget
    decision = decide_now(on_edge(150, 150, 150), cloud_was_slow)
    assert (decision.move_to, decision.reason) == (None, STAY_NO_BETTER)
    barely_better = {"cloud": Report(90.0, "cloud", 95.0, 100.0)}  # within budget, but not under 80% of 110
    assert decide_now(on_edge(110, 110, 110), barely_better).reason == STAY_NO_BETTER
    # Only itself is eligible: nowhere to go.
    only_edge = decide(102.0, "edge", 0.0, on_edge(150, 150, 150), {}, ["edge"], POLICY)
    assert only_edge.reason == STAY_NO_BETTER


def test_a_measurement_older_than_memory_s_is_tried_again() -> None:
    cloud_was_slow_long_ago = {"cloud": Report(30.0, "cloud", 140.0, 100.0)}  # 72 s before: older than 60 s
    assert decide_now(on_edge(150, 150, 150), cloud_was_slow_long_ago).move_to == "cloud"


def test_the_best_measured_placement_wins_over_an_untried_one() -> None:
    eligible = ["edge", "fog", "cloud"]
    measured = {"cloud": Report(95.0, "cloud", 40.0, 100.0)}  # fog untried, first in order
    decision = decide(102.0, "edge", 0.0, on_edge(150, 150, 150), measured, eligible, POLICY)
    assert decision.move_to == "cloud" and "p95 40 ms there" in decision.message
    decision = decide(102.0, "edge", 0.0, on_edge(150, 150, 150), {}, eligible, POLICY)
    assert decision.move_to == "fog" and "not measured recently" in decision.message


def test_no_result_at_all_counts_as_over_budget_when_frames_missed_it() -> None:
    assert decide_now(on_edge(None, None, None, missed=25)).move_to == "cloud"
    assert decide_now(on_edge(None, None, None, missed=0)).reason == STAY_OK  # not streaming


@pytest.mark.parametrize("bad", [{"recover_ratio": 0}, {"margin": 1.5}, {"min_dwell_s": -1}])
def test_policy_rejects_nonsense(bad: dict) -> None:
    with pytest.raises(ValueError):
        SwitchPolicy(**bad)


def test_the_robot_reports_each_window_p95_and_what_missed_the_deadline() -> None:
    from netapp.client.middleware import latency_report

    window = latency_report([10.0] * 10 + [150.0] * 10, lost=3, deadline_ms=100.0, window_s=1.0)
    assert window == {"p95_ms": 150.0, "deadline_ms": 100.0, "missed": 13, "window_s": 1.0}
    assert latency_report([], lost=4, deadline_ms=100.0, window_s=0.5)["p95_ms"] is None  # an outage: no results


def test_the_slope_is_a_least_squares_fit() -> None:
    from netapp_middleware.switchover.decision import slope

    assert slope([(0, 10), (1, 20), (2, 30)]) == (pytest.approx(10.0), math.inf)  # on a line: no doubt
    per, t = slope([(0, 10), (1, 30), (2, 20), (3, 40)])
    assert per == pytest.approx(8.0) and t == pytest.approx(1.89, abs=0.01)  # rising, but as much noise as trend
    assert slope([(0, 10), (1, 20)]) is None and slope([(1, 10), (1, 20), (1, 30)]) is None


def test_a_rising_trend_moves_before_a_sustained_breach_would() -> None:
    rising = on_edge(70, 80, 88, 96)  # +8.6 ms/s, in the 80..100 band, over budget within 2 s: not over yet
    decision = decide_now(rising)
    assert (decision.move_to, decision.reason) == ("cloud", MOVED)
    assert "rising 9 ms/s toward the 100 ms budget (over it in 0.5 s)" in decision.message
    # Over budget for 1 s only, rising: no need to wait for the 2 s of sustain.
    assert decide_now(on_edge(60, 80, 95, 120)).move_to == "cloud"
    # Within the dwell time, a trend waits like a breach.
    assert decide_now(rising, arrived_at=95.0).reason == STAY_DWELL


def test_the_trend_keeps_the_hysteresis_and_needs_enough_points() -> None:
    assert decide_now(on_edge(20, 40, 60, 78)).reason == STAY_OK  # rising fast, but under the 80% band
    assert decide_now(on_edge(79, 80, 81, 82)).reason == STAY_OK  # in the band, but 9 s from the budget
    assert decide_now(on_edge(96, 90, 85, 81)).reason == STAY_OK  # falling
    assert decide_now(on_edge(80, 90, 99)).reason == STAY_OK  # three points make no trend
    # The budget tightens under a steady latency (jitter around 150 ms): no trend, the sustained breach decides.
    steady = [*on_edge(140, 151, budget=1000.0), *on_edge(142, 156, start=102.0)]
    assert decide_now(steady).reason == STAY_SUSTAIN
    no_trend = SwitchPolicy(sustain_s=2.0, min_dwell_s=10.0, trend_horizon_s=0)
    assert decide(103.0, "edge", 0.0, on_edge(70, 80, 88, 96), {}, EDGE_CLOUD, no_trend).reason == STAY_OK


def test_the_sustain_window_is_what_a_move_costs_short_into_a_warm_netapp_never_longer_than_cold() -> None:
    assert sustain_for(POLICY, warm=False) == 2.0 and sustain_for(POLICY, warm=True) == 0.0
    assert sustain_for(SwitchPolicy(sustain_s=1.0, warm_sustain_s=5.0), warm=True) == 1.0
    with pytest.raises(ValueError):
        SwitchPolicy(warm_sustain_s=-1)


def test_into_a_warm_netapp_the_first_report_over_budget_moves_the_robot() -> None:
    decision = decide_now(on_edge(50, 150), warm=("cloud",))
    assert (decision.move_to, decision.reason) == ("cloud", MOVED)
    assert "a netapp is Ready there" in decision.message
    # Cold, the same report waits for the sustain window; a warm netapp elsewhere than the target changes nothing.
    assert decide_now(on_edge(50, 150)).reason == STAY_SUSTAIN
    assert decide_now(on_edge(50, 150), warm=("edge",)).reason == STAY_SUSTAIN
    half = SwitchPolicy(sustain_s=2.0, warm_sustain_s=1.0, min_dwell_s=10.0)
    assert decide_now(on_edge(50, 150), warm=("cloud",), policy=half).reason == STAY_SUSTAIN
    assert decide_now(on_edge(50, 150, 150), warm=("cloud",), policy=half).move_to == "cloud"


def test_a_warm_target_keeps_the_hysteresis_the_dwell_and_would_do_better() -> None:
    warm = ("cloud",)
    assert decide_now(on_edge(150, 90), warm=warm).move_to == "cloud"  # 90 in the band: the streak goes on
    assert decide_now(on_edge(150, 70), warm=warm).reason == STAY_OK  # under 80 %: it ended
    assert decide_now(on_edge(50, 150), warm=warm, arrived_at=95.0).reason == STAY_DWELL  # no flapping
    cloud_was_slow = {"cloud": Report(90.0, "cloud", 140.0, 100.0)}
    # Cloud was slow: no better target, so no warm one either (the cold sustain window applies, then no move).
    assert decide_now(on_edge(50, 150), cloud_was_slow, warm=warm).reason == STAY_SUSTAIN
    assert decide_now(on_edge(150, 150, 150), cloud_was_slow, warm=warm).reason == STAY_NO_BETTER


def test_a_cold_target_is_prepared_at_the_first_sign_of_a_move_not_after_the_sustained_breach() -> None:
    """`Decision.prepare`: the placement whose netapp the loop starts now, so that the move is a warm one later."""
    first_over = decide_now(on_edge(50, 150))
    assert (first_over.move_to, first_over.reason, first_over.prepare) == (None, STAY_SUSTAIN, "cloud")
    # A trend crossing the budget within prepare_horizon_s (2.7 s; a move waits for 2 s) prepares, moves nothing.
    ahead = decide_now(on_edge(80, 83.5, 87, 90.5))
    assert (ahead.move_to, ahead.reason, ahead.prepare) == (None, STAY_OK, "cloud")
    assert "over the budget in 2.7 s" in ahead.message
    near = SwitchPolicy(sustain_s=2.0, min_dwell_s=10.0, prepare_horizon_s=2.5)
    assert decide_now(on_edge(80, 83.5, 87, 90.5), policy=near).prepare is None
    # Nothing to prepare: within budget and flat or falling, already Ready there, no better placement, the dwell.
    assert decide_now(on_edge(50, 60, 99)).prepare is None
    assert decide_now(on_edge(96, 90, 85, 81)).prepare is None
    assert decide_now(on_edge(50, 150), warm=("cloud",)).prepare is None
    cloud_was_slow = {"cloud": Report(90.0, "cloud", 140.0, 100.0)}
    assert decide_now(on_edge(50, 150), cloud_was_slow).prepare is None
    assert decide_now(on_edge(50, 150), arrived_at=95.0).prepare is None
    off = SwitchPolicy(sustain_s=2.0, min_dwell_s=10.0, prepare=False)
    assert decide_now(on_edge(50, 150), policy=off).prepare is None
    assert decide_now(on_edge(80, 83.5, 87, 90.5), policy=off).prepare is None
    # The sustained breach still moves (into the prepared netapp when Ready, else it waits for it like any move).
    assert decide_now(on_edge(50, 150, 160, 170)).move_to == "cloud"
    with pytest.raises(ValueError):
        SwitchPolicy(prepare_horizon_s=-1)


def test_the_robot_reports_a_window_that_crosses_its_budget_at_once_not_at_its_end() -> None:
    import threading
    import time
    from types import SimpleNamespace

    from netapp.client.middleware import EARLY_REPORT_S, MiddlewareClient, crossed

    assert crossed([150.0, 160.0], 100.0, last_over=False)
    assert not crossed([150.0], 100.0, last_over=False)  # one result is no window
    assert not crossed([150.0, 160.0], 100.0, last_over=True)  # already told: the regular reports go on
    assert not crossed([50.0, 60.0], 100.0, last_over=False)

    stats = SimpleNamespace(lock=threading.Lock(), latencies_ms=[], lost=0, dropped=0)
    reports: list[tuple[float, dict]] = []
    stop = threading.Event()
    robot = SimpleNamespace(report=lambda endpoint, url, **body: reports.append((time.monotonic(), body)) or {})
    client = SimpleNamespace(stats=stats, url="http://netapp")
    began = time.monotonic()
    endpoint = SimpleNamespace(deployment_id="d")
    loop = threading.Thread(target=MiddlewareClient._report_loop, args=(robot, endpoint, client, 100.0, 10.0, stop))
    loop.start()
    try:
        with stats.lock:
            stats.latencies_ms += [150.0, 170.0, 160.0]  # over the 100 ms budget; the window is 10 s long
        deadline = time.monotonic() + 5
        while not reports and time.monotonic() < deadline:
            time.sleep(0.01)  # waiting on the reporter's thread
    finally:
        stop.set()
        loop.join(5)
    [(at, body)] = reports
    assert EARLY_REPORT_S <= at - began < 2.0 and body["p95_ms"] > body["deadline_ms"] == 100.0
