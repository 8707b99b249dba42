"""The families and tasks with no shared export, read from their exporters' documented output formats with tiny
models built here, and the edge cases: no detections, 1,000 candidates, a degenerate box. A frame of 128x96 is
letterboxed (or stretched) into the 64x64 input, so every coordinate must come back to the frame's pixels."""

from __future__ import annotations

import numpy as np
import pytest

from netapp.models import Detector, DetectorConfig
from netapp.results import mask_to_array, polygons_to_array
from tests.support.onnx_models import (
    POSE_POINTS,
    dfine_model,
    end2end_model,
    many_candidates_model,
    rfdetr_model,
    rtdetr_model,
    yolov8_pose_model,
    yolov8_seg_model,
)

BOX = (8.0, 16.0, 40.0, 48.0)  # input pixels of the 64x64 models
FRAME = np.full((96, 128, 3), 80, np.uint8)  # 4:3: the letterbox pads 8 px above and below (ratio 0.5)


def letterboxed(box):
    """BOX in the 128x96 frame (ratio 0.5, 8 px of padding above)."""
    x1, y1, x2, y2 = box
    return [x1 * 2, (y1 - 8) * 2, x2 * 2, (y2 - 8) * 2]


def stretched(box):
    """BOX in the 128x96 frame when the 64x64 input is a stretch (x 2, y 1.5)."""
    x1, y1, x2, y2 = box
    return [x1 * 2, y1 * 1.5, x2 * 2, y2 * 1.5]


def loaded(path, **config) -> Detector:
    detector = Detector(DetectorConfig(str(path), **config))
    detector.load()
    return detector


@pytest.mark.parametrize(
    ("build", "family", "expected", "name"),
    [
        (lambda p: end2end_model(p, [(*BOX, 0.8, 2), (*BOX, 0.5, 1), (*BOX, 0.1, 0)]), "end2end", letterboxed, "car"),
        (lambda p: rtdetr_model(p, BOX, 2), "rtdetr", stretched, "c2"),
        (lambda p: rfdetr_model(p, BOX, 3), "rfdetr", stretched, "car"),  # COCO category 3 of 91
        (lambda p: dfine_model(p, BOX, 2), "dfine", stretched, "car"),  # COCO's 80 by default
    ],
)
def test_queries_families_without_nms(tmp_path, build, family, expected, name):
    detector = loaded(build(tmp_path / f"{family}.onnx"), conf=0.3)
    assert (detector.card.family, detector.card.task) == (family, "detect")
    detections = detector.detect(FRAME)
    best = detections[0]
    assert best["class_name"] == name
    assert best["bbox"] == pytest.approx(expected(BOX), abs=0.2)
    if family == "end2end":  # no NMS: the same box under another class stays; the row under the threshold goes
        assert [d["class"] for d in detections] == [2, 1]


def test_end2end_keeps_rows_over_even_a_tiny_threshold(tmp_path):
    path = end2end_model(tmp_path / "e2e.onnx", [(*BOX, 0.001, 0), (*BOX, 0.00005, 1)])
    assert [d["class"] for d in loaded(path, conf=0.0001).detect(FRAME)] == [0]


def test_segmentation_masks_fill_their_box_in_frame_pixels(tmp_path):
    for with_metadata in (True, False):  # by Ultralytics' metadata, or by the prototypes' shape alone
        path = yolov8_seg_model(tmp_path / f"seg{with_metadata}.onnx", BOX, with_metadata=with_metadata)
        for fmt in ("polygons", "rle"):
            detector = loaded(path, mask_format=fmt)
            assert (detector.card.task, detector.card.num_classes, detector.card.mask_channels) == ("segment", 1, 32)
            (d,) = detector.detect(FRAME)
            expected = np.zeros((96, 128), bool)
            x1, y1, x2, y2 = (int(v) for v in letterboxed(BOX))
            expected[y1:y2, x1:x2] = True
            got = mask_to_array(d["mask"], 96, 128)
            assert (got & expected).sum() / (got | expected).sum() >= 0.95, fmt
            if fmt == "polygons":
                assert polygons_to_array(d["mask"]["polygons"], 96, 128).sum() == got.sum()


def test_a_detection_whose_mask_is_empty_is_dropped(tmp_path):
    path = yolov8_seg_model(tmp_path / "seg.onnx", BOX)
    detector = loaded(path)
    found = detector.family.candidates(
        [o[0] for o in detector.session.run(None, detector.prepare(FRAME, {}).feeds)], detector.card, 0.3
    )
    found.extra[:] = 0.0  # coefficients that make every logit 0: no pixel is over it
    from netapp.models.tasks import detections

    assert detections(found, detector.card, detector.prepare(FRAME, {}).placement, detector.options) == []


def test_pose_keypoints_come_back_to_the_frame(tmp_path):
    detector = loaded(yolov8_pose_model(tmp_path / "pose.onnx", BOX))
    card = detector.card
    assert (card.task, card.num_classes, card.keypoints, card.keypoint_names[0]) == ("pose", 1, (17, 3), "nose")
    (d,) = detector.detect(FRAME)
    expected = [[x * 2, (y - 8) * 2, v] for x, y, v in POSE_POINTS]
    assert np.asarray(d["keypoints"]) == pytest.approx(np.asarray(expected), abs=0.05)


def test_no_detections_is_an_empty_list(tmp_path):
    for path in (end2end_model(tmp_path / "none.onnx", []), yolov8_seg_model(tmp_path / "seg.onnx", BOX)):
        assert loaded(path, conf=0.99).detect(FRAME) == []


def test_a_thousand_candidates_and_a_degenerate_box(tmp_path):
    detector = loaded(many_candidates_model(tmp_path / "many.onnx"), conf=0.25, iou=0.5, max_detections=50)
    frame = np.full((256, 256, 3), 80, np.uint8)
    detections = detector.detect(frame)
    assert len(detections) == 50  # the cap, after NMS
    scores = [d["score"] for d in detections]
    assert scores == sorted(scores, reverse=True) and scores[0] == pytest.approx(0.95)
    x1, y1, x2, y2 = detections[0]["bbox"]  # the degenerate box is sent as it is, a point, inside the frame
    assert x1 == x2 and y1 == y2 and 0 <= x1 <= 256 and 0 <= y1 <= 256
    everything = loaded(many_candidates_model(tmp_path / "many2.onnx"), conf=0.0001, iou=0.99, max_detections=1000)
    assert 500 < len(everything.detect(frame)) <= 1000
