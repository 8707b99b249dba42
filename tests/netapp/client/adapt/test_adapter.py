"""The adapter between a client and its controller, on a clock the test turns (no client, no sockets)."""

from __future__ import annotations

from netapp.accuracy import load_profile
from netapp.client.adapt import AdaptConfig, Choice
from netapp.client.adapt.adapter import MAX_CHANGES, UplinkAdapter
from netapp.client.timing import LatencyBreakdown


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def adapter(**config: object) -> tuple[UplinkAdapter, Clock, list[Choice]]:
    profile = load_profile("yolox_nano")
    assert profile is not None
    clock, applied = Clock(), []
    return UplinkAdapter(profile, AdaptConfig(**config), applied.append, clock), clock, applied  # type: ignore[arg-type]


def parts(uplink_ms: float) -> LatencyBreakdown:
    return LatencyBreakdown(uplink_ms, 1.0, 20.0, 10.0, uplink_ms + 31.0)


def test_the_first_frame_builds_the_ladder_for_the_netapps_input_and_applies_its_first_rung() -> None:
    adapt, _, applied = adapter()
    adapt.begin((1280, 720), (416, 416))
    assert adapt.ladder is not None and all((r.long_side or 1280) <= 416 for r in adapt.ladder.rungs)
    assert applied == [adapt.choice] and applied[0].rung == 0
    adapt.begin((640, 480), None)  # once
    assert len(applied) == 1


def test_a_result_says_what_its_frame_was_sent_with_and_teaches_the_controller() -> None:
    adapt, clock, applied = adapter()
    adapt.begin((1280, 720), (416, 416))
    first = adapt.choice
    assert first is not None
    for i in range(40):  # a fast link: it probes up after the hold
        adapt.admit()
        adapt.sent(i, 5_000)
        clock.now += 0.1
        sent = adapt.result(i, 50.0, parts(15.0))
        assert sent is not None and sent["bytes"] == 5_000
    assert sent["long_side"] == adapt.choice.long_side or len(applied) > 1
    assert adapt.choice is not None and adapt.choice.rung > first.rung
    assert adapt.result(999, 50.0, parts(15.0)) is None  # a frame it never saw
    report = adapt.report()
    assert report["within_budget"] == 1.0 and report["change_count"] == len(applied) - 0
    assert report["changes"][0]["t_s"] == 0 and report["changes"][-1]["reason"] == "probe up"


def test_the_frame_rate_is_kept_when_it_goes_down() -> None:
    adapt, clock, applied = adapter()
    adapt.begin((1280, 720), (416, 416))
    for i in range(3):  # 4.8 KB take 150 ms: 0.25 Mbit/s, the cheapest rung does not fit 10 fps
        adapt.admit()
        adapt.sent(i, 4_800)
        clock.now += 0.1
        adapt.result(i, 190.0, parts(160.0))
    choice = adapt.choice
    assert choice is not None and choice.rung == 0 and choice.fps < 10
    admitted, skipped = 0, adapt.report()["skipped_for_rate"]
    for _ in range(50):  # the robot offers 10 fps for 5 s
        admitted += adapt.admit()
        clock.now += 0.1
    assert abs(admitted / 5 - choice.fps) <= 1.0 and adapt.report()["skipped_for_rate"] - skipped == 50 - admitted


def test_the_robots_own_frame_rate_is_measured() -> None:
    adapt, clock, _ = adapter(source_fps=10)
    adapt.begin((1280, 720), None)
    for _ in range(20):
        assert adapt.admit()
        clock.now += 0.2
    assert adapt._controller is not None and adapt._controller.config.source_fps == 5.0


def test_the_changes_kept_are_bounded() -> None:
    adapt, clock, applied = adapter(hold_s=0.0, probe_window_s=0.0)
    adapt.begin((1280, 720), None)
    for i in range(4 * MAX_CHANGES):  # a link that swings every result
        adapt.sent(i, 5_000)
        clock.now += 0.1
        adapt.result(i, 50.0 if i % 4 < 2 else 400.0, parts(15.0 if i % 4 < 2 else 370.0))
    report = adapt.report()
    assert len(report["changes"]) <= MAX_CHANGES < report["change_count"] == len(applied)


def test_no_frame_goes_while_one_in_flight_is_overdue_and_none_that_cannot_make_the_budget() -> None:
    adapt, clock, _ = adapter(switch_codec=True)
    adapt.begin((1280, 720), None)
    for i in range(30):  # 4 Mbit/s: 16 KB frames back in 80 ms
        assert adapt.admit()
        adapt.sent(i, 16_000)
        clock.now += 0.08
        adapt.result(i, 80.0, parts(49.0))
        clock.now += 0.02
    assert adapt.in_flight_cap() is None
    adapt.admit()
    adapt.sent(100, 16_000)  # the link falls to 0.25 Mbit/s under it
    clock.now += 0.1
    assert adapt.in_flight_cap() == 1  # 100 ms without its result: the next frame waits for it
    clock.now += 0.45
    adapt.result(100, 550.0, parts(519.0))  # its result: the link is slow
    assert adapt.in_flight_cap() is None
    assert adapt.choice is not None and adapt.choice.codec == "h264"
    adapt.sent(101, 16_000)  # one more big frame went before that result (a second netapp's, say)
    clock.now += 0.05
    # A frame now would queue half a second behind it: dropped (counted), not sent.
    assert not adapt.admit() and adapt.report()["skipped_for_budget"] == 1


def test_a_transport_of_h264_alone_gets_the_profiles_h264_rows() -> None:
    adapt, _, applied = adapter(codec="h264")  # RTP, or codec="h264": the same rule as a switching transport's
    adapt.begin((1280, 720), None)
    assert adapt.ladder is not None and adapt.ladder.rungs[0].codec == "h264"
    first = applied[0]
    assert first.codec is None and first.bitrate_kbps == adapt.ladder.rungs[0].bitrate_kbps  # the profile's own
