"""The accuracy profile a robot ships with: it loads, it says the cheapest setting above a floor, bad profiles are
refused with what is wrong; and a downsized frame's boxes, scaled back, land where the full-size frame's are."""

from __future__ import annotations

import json

import cv2
import pytest

from netapp.accuracy import AccuracyProfile, Setting, load_profile
from netapp.apps.profiling import at_setting, in_source_pixels
from netapp.models.matching import box_iou


def profile(*settings: Setting) -> AccuracyProfile:
    return AccuracyProfile("m", "v.avi", (1280, 720), 10, "2026-11-24", settings)


def test_the_shipped_profile_loads_and_names_a_cheap_setting() -> None:
    shipped = load_profile("yolox_nano")
    assert shipped is not None and shipped.model == "yolox_nano" and shipped.frames >= 20
    full = next(s for s in shipped.settings if (s.long_side, s.quality) == (None, 85))
    pick = shipped.cheapest(0.95)
    assert pick is not None and pick.f1 >= 0.95 and pick.bytes_per_frame * 4 <= full.bytes_per_frame
    assert load_profile("no-such-model") is None


def test_cheapest_keeps_the_floor() -> None:
    big, small, tiny = Setting(None, 85, 0.99, 90_000), Setting(416, 70, 0.96, 11_000), Setting(256, 20, 0.8, 2_000)
    p = profile(big, small, tiny)
    assert p.cheapest(0.95) == small and p.cheapest(0.99) == big and p.cheapest(0.5) == tiny
    assert p.cheapest(1.0) is None
    assert AccuracyProfile.from_json(p.to_json()) == p
    # masks and keypoints, and the model file's digest, survive the round trip; a profile without them still loads
    rich = AccuracyProfile(
        "m", "v.avi", (1280, 720), 10, "2026-11-27", (Setting(None, 85, 0.99, 9e4, 0.93, 0.88),), "a" * 64
    )
    assert AccuracyProfile.from_json(rich.to_json()) == rich
    old = json.loads(p.to_json())
    for row in old["settings"]:
        del row["mask_iou"], row["oks"]
    del old["model_sha256"]
    assert AccuracyProfile.from_json(json.dumps(old)) == p


@pytest.mark.parametrize(
    "change, says",
    [
        (lambda d: d.pop("settings"), "settings"),
        (lambda d: d.update(settings=[]), "1 to"),
        (lambda d: d.update(settings=d["settings"] * 1001), "1 to"),
        (lambda d: d["settings"][0].update(f1=1.5), "out of range"),
        (lambda d: d["settings"][0].update(quality=0), "out of range"),
        (lambda d: d["settings"][0].update(long_side=8), "under 16"),
        (lambda d: d["settings"][0].update(bytes_per_frame="many"), "not an accuracy profile"),
        (lambda d: d["settings"][0].update(mask_iou=1.2), "out of range"),
        (lambda d: d["settings"][0].update(oks=-0.1), "out of range"),
        (lambda d: d.update(model_sha256="not-hex"), "model_sha256"),
    ],
)
def test_a_bad_profile_is_refused_saying_what_is_wrong(change, says) -> None:
    data = json.loads(profile(Setting(None, 85, 0.99, 90_000)).to_json())
    change(data)
    with pytest.raises(ValueError, match=says):
        AccuracyProfile.from_json(json.dumps(data))


def test_boxes_of_a_downsized_frame_land_where_the_full_frames_do(real_model_path, media_dir) -> None:
    from netapp.models import Detector, DetectorConfig

    detector = Detector(DetectorConfig(str(real_model_path)))
    detector.load()
    frame = cv2.imread(str(media_dir / "dog.jpg"))  # 768x576: dog, bicycle, car
    full = detector.detect(frame)
    image, _ = at_setting(frame, 416, 70)
    assert max(image.shape[:2]) == 416
    small = in_source_pixels(detector.detect(image), (image.shape[1], image.shape[0]), (768, 576))
    for want in [d for d in full if d["score"] >= 0.8]:
        same = small[small.class_id == want["class"]]
        best = max((box.tolist() for box in same.xyxy), key=lambda box: box_iou(box, want["bbox"]))
        assert box_iou(best, want["bbox"]) >= 0.8, (want, best)
