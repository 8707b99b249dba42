"""The ladder a controller climbs, from the shipped YOLOX-Nano profile and from made-up ones."""

from __future__ import annotations

from netapp.accuracy import AccuracyProfile, Setting, load_profile
from netapp.client.adapt import Ladder


def profile(*settings: Setting) -> AccuracyProfile:
    return AccuracyProfile("m", "v.avi", (1280, 720), 10, "2026-11-24", settings)


def test_rungs_stay_between_the_floor_and_the_knee_cheapest_first() -> None:
    shipped = load_profile("yolox_nano")
    assert shipped is not None
    ladder = Ladder.from_profile(shipped, floor=0.9)
    sizes = [r.bytes_per_frame for r in ladder.rungs]
    assert sizes == sorted(sizes) and len(ladder) >= 3
    assert all(r.f1 >= 0.9 for r in ladder.rungs)
    best = max(s.f1 for s in shipped.settings)
    assert ladder.rungs[-1].f1 >= best - 0.025  # the knee: as good as the best
    assert ladder.rungs[-1].bytes_per_frame < 0.25 * 94_000  # and far cheaper than today's frames
    assert [r.f1 for r in ladder.rungs] == sorted(r.f1 for r in ladder.rungs)  # more bytes buy more F1
    assert all(b >= a * 1.2 for a, b in zip(sizes, sizes[1:], strict=False))


def test_a_setting_dearer_and_no_better_is_never_a_rung() -> None:
    ladder = Ladder.from_profile(
        profile(
            Setting(320, 50, 0.91, 5_000),
            Setting(640, 20, 0.90, 9_000),  # more bytes, worse
            Setting(640, 50, 0.95, 12_000),
            Setting(None, 95, 0.99, 90_000),
        ),
        floor=0.9,
        knee_tolerance=0.01,
    )
    assert [(r.long_side, r.quality) for r in ladder.rungs] == [(320, 50), (640, 50), (None, 95)]


def test_no_setting_reaches_the_floor_the_best_alone() -> None:
    ladder = Ladder.from_profile(profile(Setting(320, 50, 0.7, 5_000), Setting(None, 95, 0.8, 90_000)), floor=0.9)
    assert not ladder.reaches_floor
    assert [(r.long_side, r.quality) for r in ladder.rungs] == [(None, 95)]


def test_never_more_pixels_than_the_source() -> None:
    shipped = load_profile("yolox_nano")
    assert shipped is not None
    ladder = Ladder.from_profile(shipped, floor=0.9, source_long_side=640)
    assert all(r.long_side is None or r.long_side < 640 for r in ladder.rungs)


def test_a_transport_of_h264_alone_climbs_the_profiles_h264_rows() -> None:
    shipped = load_profile("yolox_nano")
    assert shipped is not None
    ladder = Ladder.from_profile(shipped, floor=0.9, jpeg=False)  # RTP, or codec="h264": one rule, not a guess
    video = [r for r in ladder.rungs if r.codec == "h264"]
    assert ladder.rungs[0].codec == "h264" and video and all(r.bitrate_kbps for r in video)
    assert all(r.f1 >= 0.9 for r in ladder.rungs)
    # Above the best H.264 row the profile measured, only JPEG's better rungs, priced as H.264 by the controller.
    above = [r for r in ladder.rungs if r.codec == "jpeg"]
    assert all(r.f1 > video[-1].f1 and r.bytes_per_frame / 3 >= video[-1].bytes_per_frame * 1.2 for r in above)
    # A profile without H.264 rows: JPEG's ladder, as before.
    jpeg_only = profile(Setting(320, 50, 0.91, 5_000), Setting(640, 50, 0.95, 12_000))
    assert [r.codec for r in Ladder.from_profile(jpeg_only, floor=0.9, jpeg=False).rungs] == ["jpeg", "jpeg"]
