"""Accuracy profiles for any model: mask IoU and COCO's OKS between two runs, what shrinking and JPEG do to masks and
keypoints, and `netapp profile MODEL` writing a profile that names its model file's SHA-256."""

from __future__ import annotations

import hashlib
import json
import math

import cv2
import numpy as np
import pytest

from netapp.accuracy import AccuracyProfile
from netapp.apps.profiling import in_source_pixels, make_profile, measure
from netapp.cli import main
from netapp.models.matching import (
    COCO_SIGMAS,
    UNIFORM_SIGMA,
    agreement,
    frame_agreement,
    keypoint_similarity,
    mask_iou,
)
from netapp.results import Detection, Mask
from tests.support.paths import SHARED

EXPORTS = SHARED / "models" / "exports"


def test_mask_iou() -> None:
    a = np.zeros((10, 10), bool)
    b = np.zeros((10, 10), bool)
    assert mask_iou(a, b) == 1.0  # both empty: they agree
    a[0:4, 0:5] = True  # 20 pixels
    b[2:6, 0:5] = True  # 20 pixels, 10 shared
    assert mask_iou(a, b) == pytest.approx(10 / 30)
    assert mask_iou(a, a) == 1.0 and mask_iou(a, ~a) == 0.0


def test_oks_is_cocos() -> None:
    person = [[10.0 * i, 5.0 * i, 0.9] for i in range(17)]
    assert keypoint_similarity(person, person, 400.0) == 1.0
    # one keypoint off by d, the rest exact: exp(-d^2 / (2 area (2 sigma)^2)) for that one, averaged over 17
    moved = [list(p) for p in person]
    moved[11][0] += 6.0  # the left hip, sigma 0.107
    e = math.exp(-36.0 / (2 * 400.0 * (2 * COCO_SIGMAS[11]) ** 2))
    assert keypoint_similarity(person, moved, 400.0) == pytest.approx((16 + e) / 17)
    # a keypoint the reference does not see does not count
    hidden = [list(p) for p in person]
    hidden[11][2] = 0.1
    assert keypoint_similarity(hidden, moved, 400.0) == 1.0
    # another skeleton: one sigma for all
    three = [[0.0, 0.0, 1.0], [10.0, 0.0, 1.0], [20.0, 0.0, 1.0]]
    off = [[3.0, 4.0, 1.0], [10.0, 0.0, 1.0], [20.0, 0.0, 1.0]]
    e = math.exp(-25.0 / (2 * 100.0 * (2 * UNIFORM_SIGMA) ** 2))
    assert keypoint_similarity(three, off, 100.0) == pytest.approx((2 + e) / 3)
    assert keypoint_similarity(three, person, 100.0) is None  # different skeletons
    assert keypoint_similarity([[0.0, 0.0, 0.0]], [[0.0, 0.0, 0.0]], 100.0) is None  # nothing visible


def test_frame_agreement_compares_the_matched_pairs_masks_and_keypoints() -> None:
    full = np.zeros((20, 20), bool)
    full[0:10, 0:10] = True
    half = np.zeros((20, 20), bool)
    half[0:10, 0:5] = True
    kp = [[2.0, 2.0, 0.9], [8.0, 8.0, 0.9]]
    ref = [{"bbox": [0, 0, 10, 10], "class": 0, "mask": full, "keypoints": kp}]
    cand = [
        {"bbox": [0, 0, 10, 10], "class": 0, "mask": half, "keypoints": kp},
        {"bbox": [12, 12, 20, 20], "class": 0, "mask": full},  # no match: counts against F1 only
    ]
    frame = frame_agreement(ref, cand)
    assert (frame.matched, frame.found, frame.expected) == (1, 2, 1)
    assert frame.mask_ious == (0.5,) and frame.oks == (1.0,)
    summary = agreement([frame, frame_agreement([], [])])
    assert summary.f1 == pytest.approx(2 / 3) and summary.mask_iou == 0.5 and summary.oks == 1.0
    assert agreement([frame_agreement([{"bbox": [0, 0, 1, 1], "class": 0}], [])]).mask_iou is None


# A real segmenter and keypoint finder, small enough to read: each bright blob is an object, its pixels the mask,
# its extreme points and centre the keypoints. What a real model does with a shrunk, compressed frame it does too:
# its masks lose their edges and its points move.
def blob_segmenter(fmt: str):
    def detect(frame: np.ndarray) -> list[dict]:
        gray = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        count, labels, stats, centroids = cv2.connectedComponentsWithStats((gray > 128).astype(np.uint8))
        out = []
        for i in range(1, count):
            x, y, w, h, area = stats[i]
            if area < 20:
                continue
            mask = labels == i
            ys, xs = np.nonzero(mask)
            points = [(xs.min(), ys[xs.argmin()]), (xs.max(), ys[xs.argmax()]), tuple(centroids[i])]
            keypoints = [[float(px), float(py), 0.9] for px, py in points]
            bbox = [float(x), float(y), float(x + w), float(y + h)]
            out.append(Detection(bbox, 0.9, 0, "blob", Mask.from_array(mask, fmt=fmt), keypoints).to_wire())
        return out

    return detect


def blob_frames(count: int = 3) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    frames = []
    for i in range(count):
        frame = rng.integers(0, 60, (480, 640, 3), dtype=np.uint8)  # texture for JPEG to chew on
        cv2.ellipse(frame, (200 + 20 * i, 240), (90, 50), 20, 0, 360, (255, 255, 255), -1)
        cv2.ellipse(frame, (470, 150 + 30 * i), (40, 70), -30, 0, 360, (230, 230, 230), -1)
        frames.append(frame)
    return frames


@pytest.mark.parametrize("fmt", ["polygons", "rle"])
def test_masks_and_keypoints_lose_as_frames_shrink(fmt) -> None:
    settings = {(s.long_side, s.quality): s for s in measure(blob_segmenter(fmt), blob_frames(), [None, 96], [95])}
    full, small = settings[(None, 95)], settings[(96, 95)]
    assert full.f1 == 1.0 and full.mask_iou >= 0.97 and full.oks >= 0.97
    assert small.f1 == 1.0  # the blobs are still found...
    assert 0.5 < small.mask_iou < full.mask_iou and small.oks < full.oks  # ...with rougher edges and moved points


def test_in_source_pixels_takes_masks_and_keypoints_to_the_source_frame() -> None:
    mask = np.zeros((48, 64), bool)
    mask[8:24, 16:32] = True
    found = Detection([16, 8, 32, 24], 0.9, 0, "x", Mask.from_array(mask, fmt="rle"), [[16.0, 8.0, 1.0]]).to_wire()
    back = in_source_pixels([found], (64, 48), (640, 480))
    assert back.xyxy.tolist() == [[160, 80, 320, 240]] and back.keypoints.tolist() == [[[160.0, 80.0, 1.0]]]
    mask = back.mask_array(0, 480, 640)
    assert mask.shape == (480, 640) and mask[80:240, 160:320].all() and mask.sum() == 160 * 160


def test_netapp_profile_writes_a_profile_naming_its_models_sha256(tiny_model_path, tmp_path, capsys) -> None:
    for i, frame in enumerate(blob_frames(2)):
        cv2.imwrite(str(tmp_path / f"f{i}.jpg"), frame)
    out = tmp_path / "tiny.json"
    argv = ["profile", str(tiny_model_path), "--media", str(tmp_path), "--sides", "full,320", "--qualities", "85,40"]
    assert main([*argv, "--out", str(out)]) == 0
    profile = AccuracyProfile.from_json(out.read_text())
    assert profile.model == "tiny_yolox" and profile.frames == 2 and profile.source_size == (640, 480)
    assert profile.model_sha256 == hashlib.sha256(tiny_model_path.read_bytes()).hexdigest()
    assert {(s.long_side, s.quality) for s in profile.settings} == {(None, 85), (None, 40), (320, 85), (320, 40)}
    assert all(s.f1 == 1.0 and s.mask_iou is None and s.oks is None for s in profile.settings)  # boxes only
    assert "wrote" in capsys.readouterr().out


def test_netapp_profile_refuses_what_it_cannot_read(tiny_model_path, tmp_path, capsys) -> None:
    assert main(["profile", str(tiny_model_path), "--media", str(tmp_path / "none.mp4")]) == 2
    assert "does not exist" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["profile", str(tiny_model_path), "--media", str(tmp_path / "empty")]) == 2
    assert "no frames could be read" in capsys.readouterr().err
    with pytest.raises(SystemExit, match="--qualities takes numbers"):
        main(["profile", str(tiny_model_path), "--media", str(tmp_path), "--qualities", "high"])


@pytest.mark.parametrize(
    "export, field",
    [("yolo11n.onnx", None), ("yolo11n-seg.onnx", "mask_iou"), ("yolo11n-pose.onnx", "oks")],
)
def test_a_profile_of_a_shared_export(export, field, media_dir, tmp_path) -> None:
    """A real Ultralytics export (untrained weights, so its scores are tiny: the references' threshold)."""
    from netapp.models import Detector, DetectorConfig

    path = EXPORTS / export
    if not path.is_file():
        pytest.skip(f"{path} is absent (../shared/models/exports)")
    detector = Detector(DetectorConfig(str(path), conf=0.0001, iou=0.7, max_detections=50))
    try:
        detector.load()
    except ValueError as exc:
        pytest.skip(f"this netapp's model layer does not read {export} yet: {exc}")
    profile = make_profile(path, detector.name, detector.detect, media_dir / "dog.jpg", 1, (None, 320), (90,))
    assert profile.model_sha256 == hashlib.sha256(path.read_bytes()).hexdigest()
    full, small = profile.settings
    assert full.f1 > small.f1 and 0 < full.f1 <= 1  # the same image at 90 agrees more than at 320 pixels
    if field is not None:
        kept = getattr(full, field)
        assert kept is not None and 0 < kept <= 1, profile
    json.loads(profile.to_json())
