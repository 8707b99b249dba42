"""Issue 43: the codec is a setting the controller chooses. H.264 rungs (the profile's) below JPEG's where the
transport carries both; the controller takes them where the uplink is too thin for JPEG above the floor, and JPEG
back where it is wide (pure: `tests.support.uplink_sim`)."""

from __future__ import annotations

import pytest

from netapp.accuracy import AccuracyProfile, load_profile
from netapp.client.adapt import AdaptConfig, Controller, Ladder
from tests.support.uplink_sim import simulate


@pytest.fixture(scope="module")
def shipped() -> AccuracyProfile:
    profile = load_profile("yolox_nano")
    assert profile is not None
    return profile


@pytest.fixture(scope="module")
def ladder(shipped: AccuracyProfile) -> Ladder:
    return Ladder.from_profile(shipped, floor=0.9, h264=True)


def test_h264_rungs_go_below_jpeg_and_only_where_jpeg_cannot(shipped: AccuracyProfile, ladder: Ladder) -> None:
    codecs = [r.codec for r in ladder.rungs]
    assert codecs[0] == "h264" and codecs[-1] == "jpeg"
    assert codecs == sorted(codecs)  # "h264" < "jpeg": every H.264 rung below every JPEG one
    cheapest_jpeg = next(r for r in ladder.rungs if r.codec == "jpeg")
    video = [r for r in ladder.rungs if r.codec == "h264"]
    assert all(r.bytes_per_frame < cheapest_jpeg.bytes_per_frame and r.bitrate_kbps for r in video)
    assert all(r.f1 >= 0.9 for r in ladder.rungs)
    # Without the switch (a transport of one codec, or --adapt auto-one-codec) the ladder is JPEG's, as before.
    assert {r.codec for r in Ladder.from_profile(shipped, floor=0.9).rungs} == {"jpeg"}


def test_a_quarter_megabit_gets_h264_at_the_full_frame_rate_above_the_floor(ladder: Ladder) -> None:
    controller = Controller(ladder, AdaptConfig(switch_codec=True))
    trace = simulate(controller, lambda t: 0.25, 60)
    settled = [c for t, c in trace.choices if t > 0] or [controller.choice]
    last = settled[-1]
    assert last.codec == "h264" and last.bitrate_kbps is not None and last.fps == 10
    assert ladder.rungs[last.rung].f1 >= 0.9
    late = [lat for t, lat, _, _ in trace.results if t > 20]
    assert len(late) >= 9 * 40 and max(late) <= controller.config.latency_budget_ms


def test_a_wide_link_gets_jpeg(ladder: Ladder) -> None:
    controller = Controller(ladder, AdaptConfig(switch_codec=True))
    simulate(controller, lambda t: 4.0, 60)
    assert controller.choice.codec == "jpeg" and controller.choice.bitrate_kbps is None


def test_a_swing_switches_codec_between_frames_and_back_within_a_second(ladder: Ladder) -> None:
    controller = Controller(ladder, AdaptConfig(switch_codec=True))
    trace = simulate(controller, lambda t: 0.25 if 30 <= t < 60 else 4.0, 90)
    at = {t: c.codec for t, c in trace.choices}
    before = [c for t, c in at.items() if t < 30]
    thin = [c for t, c in at.items() if 30 <= t < 60]
    after = [c for t, c in at.items() if t >= 60]
    assert before[-1] == "jpeg" and "h264" in thin and thin[-1] == "h264" and after[-1] == "jpeg"
    budget = controller.config.latency_budget_ms
    # Late after the step down: the two frames in flight at 4 Mbit/s's top rung (16.6 KB) take 1.06 s to drain at
    # 0.25 Mbit/s whatever the controller does; the first result of the drop (1.5x over the budget) changes the choice.
    drain_s = 2 * ladder.rungs[-1].bytes_per_frame * 8 / 0.25e6
    for step, allowed in ((30.0, drain_s + 0.15), (60.0, 1.0)):
        late = [t for t, lat, _, _ in trace.results if step <= t < step + 30 and lat > budget]
        assert not late or max(late) - step <= allowed, (step, late)


def test_without_the_switch_a_choice_names_no_codec(ladder: Ladder) -> None:
    controller = Controller(Ladder(tuple(r for r in ladder.rungs if r.codec == "jpeg"), 0.9, True))
    assert controller.choice.codec is None and controller.choice.settings()["codec"] is None


def test_each_codec_learns_its_own_bytes() -> None:
    from netapp.client.adapt.estimate import UplinkEstimate

    estimate = UplinkEstimate()
    for _ in range(20):  # H.264 frames at half the profile's bytes say nothing of a JPEG's
        estimate.add(1000, 80.0, 20.0, 2000.0, codec="h264")
    assert estimate.scale_of("h264") < 0.6 and estimate.scale_of("jpeg") == 1.0 and estimate.scale == 1.0
