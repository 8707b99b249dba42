"""The controller's rules, each on its own, over a deterministic simulated uplink (`tests.support.uplink_sim`)."""

from __future__ import annotations

import pytest

from netapp.accuracy import load_profile
from netapp.client.adapt import AdaptConfig, Controller, Ladder, Observation
from tests.support.uplink_sim import simulate


@pytest.fixture(scope="module")
def ladder() -> Ladder:
    shipped = load_profile("yolox_nano")
    assert shipped is not None
    return Ladder.from_profile(shipped, floor=0.9)


def steady(mbit: float):
    return lambda t: mbit


def test_it_climbs_to_the_knee_on_a_fast_link_one_step_per_hold(ladder: Ladder) -> None:
    controller = Controller(ladder, AdaptConfig(hold_s=2.0))
    trace = simulate(controller, steady(15.6), 30)
    ups = [(t, c) for t, c in trace.choices[1:]]
    assert [c.rung for _, c in ups] == list(range(1, ladder.top + 1))  # one rung at a time, to the top, no further
    times = [0.0] + [t for t, _ in ups]
    assert all(b - a >= 2.0 for a, b in zip(times, times[1:], strict=False))  # never before the hold


def test_a_drop_steps_down_within_two_results(ladder: Ladder) -> None:
    controller = Controller(ladder)
    drop_at = 20.0
    trace = simulate(controller, lambda t: 1.5 if t >= drop_at else 15.6, 30)
    before = trace.changes_between(0, drop_at)[-1][1]
    assert before.rung == ladder.top
    first_down = next(t for t, c in trace.choices if t >= drop_at)
    slowed = [r for r in trace.results if r[0] >= drop_at and r[3] == before.version and r[1] > 0]
    # results of frames that crossed the slow link, up to the change: at most two
    assert len([r for r in slowed if r[0] <= first_down]) <= 2
    after = [c for t, c in trace.choices if t >= drop_at]
    assert after[0].rung < before.rung and after[0].reason == "uplink slower"
    late = [lat for t, lat, _, _ in trace.results if t >= drop_at + 2]
    assert late and max(late) <= controller.config.latency_budget_ms


def test_no_oscillation_on_a_steady_link(ladder: Ladder) -> None:
    for mbit in (1.5, 4.0, 15.6):
        controller = Controller(ladder)
        trace = simulate(controller, steady(mbit), 120)
        assert not trace.changes_between(30, 120), mbit  # settled within 30 s, then not one change
        assert all(lat <= controller.config.latency_budget_ms for t, lat, _, _ in trace.results if t > 30)


def test_never_below_the_floor_the_frame_rate_gives_way(ladder: Ladder) -> None:
    controller = Controller(ladder)
    trace = simulate(controller, lambda t: 0.25 if 20 <= t < 50 else 4.0, 80)
    assert all(ladder.rungs[c.rung].f1 >= 0.9 for _, c in trace.choices)
    thin = [c for t, c in trace.choices if 20 <= t < 50]
    assert thin[-1].rung == 0 and thin[-1].fps < 10
    assert all(c.fps == 10 for t, c in trace.choices if t < 20)  # the frame rate only when the cheapest rung fails
    assert trace.choices[-1][1].fps == 10  # and it comes back


def test_the_frame_rate_stays_while_the_cheapest_rung_fits(ladder: Ladder) -> None:
    for mbit in (0.6, 1.5, 4.0):
        controller = Controller(ladder)
        trace = simulate(controller, steady(mbit), 40)
        assert all(c.fps == 10 for _, c in trace.choices), mbit


def observation(controller: Controller, t: float, latency_ms: float, bytes_sent: int = 5_000) -> Observation:
    return Observation(t, controller.choice.version, bytes_sent, latency_ms, 20.0)


def test_a_failed_probe_goes_back_and_doubles_the_hold(ladder: Ladder) -> None:
    controller = Controller(ladder, AdaptConfig(hold_s=2.0))
    t = 0.0
    probe = None
    while probe is None:  # a fast, steady link: results well within the budget
        t += 0.1
        probe = controller.observe(observation(controller, t, 45.0))
    assert probe.rung == 1 and probe.reason == "probe up" and t >= 2.0
    t += 0.1
    back = controller.observe(observation(controller, t, 160.0))  # on probation, one result over the budget
    assert back is not None and back.rung == 0 and back.reason == "probe failed"
    failed_at = t
    again = None
    while again is None:
        t += 0.1
        again = controller.observe(observation(controller, t, 45.0))
    assert again.rung == 1 and t - failed_at >= 4.0  # the hold doubled


def test_results_of_frames_sent_before_a_change_do_not_change_it_again(ladder: Ladder) -> None:
    controller = Controller(ladder, AdaptConfig(start_rung=ladder.top))
    old = controller.choice.version
    for i in range(5):  # a fast link
        assert controller.observe(Observation(0.1 * i, old, 16_000, 60.0, 20.0)) is None
    first = controller.observe(Observation(1.0, old, 16_000, 200.0, 20.0))
    assert first is None  # one slow result may be jitter (under 1.5 times the budget)
    down = controller.observe(Observation(1.1, old, 16_000, 200.0, 20.0))
    assert down is not None and down.rung < ladder.top
    assert controller.observe(Observation(1.2, old, 16_000, 600.0, 20.0)) is None  # stale


def test_one_result_over_the_budget_is_jitter_two_step_down(ladder: Ladder) -> None:
    controller = Controller(ladder, AdaptConfig(start_rung=3, hold_s=100))
    for i in range(5):
        assert controller.observe(observation(controller, 0.1 * i, 45.0)) is None
    assert controller.observe(observation(controller, 1.0, 160.0)) is None
    assert controller.observe(observation(controller, 1.1, 45.0)) is None
    assert controller.observe(observation(controller, 1.2, 160.0)) is None
    down = controller.observe(observation(controller, 1.3, 160.0))
    assert down is not None and down.rung < 3


def test_two_missed_frames_step_down(ladder: Ladder) -> None:
    controller = Controller(ladder, AdaptConfig(start_rung=2))
    assert controller.missed(1.0) is None
    down = controller.missed(1.2)
    assert down is not None and down.rung == 1


def test_results_over_the_budget_at_the_cheapest_rung_leave_the_frame_rate(ladder: Ladder) -> None:
    """A queue at the netapp makes results late whatever the uplink: the frame rate answers the uplink alone."""
    controller = Controller(ladder)
    for i in range(10):  # small frames, a fast uplink, a slow netapp
        assert controller.observe(Observation(0.1 * i, 0, 5_000, 400.0, 370.0)) is None
    assert controller.choice.fps == 10


def test_a_queue_at_the_netapp_does_not_cost_accuracy(ladder: Ladder) -> None:
    controller = Controller(ladder, AdaptConfig(start_rung=3, hold_s=100))
    for i in range(20):  # the frames cross the uplink in 30 ms; the netapp's queue makes them late
        assert controller.observe(Observation(0.1 * i, 0, 9_000, 230.0, 200.0)) is None
    assert controller.choice.rung == 3


def test_h264_gets_a_bitrate_and_keeps_its_resolution_while_the_rung_holds(ladder: Ladder) -> None:
    controller = Controller(ladder, AdaptConfig(codec="h264"))
    trace = simulate(controller, steady(4.0), 40)
    choices = [c for _, c in trace.choices]
    assert all(c.bitrate_kbps is not None and c.bitrate_kbps > 0 for c in choices)
    assert choices[-1].rung > 0
    assert all((a.long_side == b.long_side) or (a.rung != b.rung) for a, b in zip(choices, choices[1:], strict=False))


def test_bad_knobs_are_refused() -> None:
    with pytest.raises(ValueError):
        AdaptConfig(latency_budget_ms=0)
    with pytest.raises(ValueError):
        AdaptConfig(codec="vp9")
