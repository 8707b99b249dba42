"""No frame lost to one detection (issue 44, item 2): every family and task, decoded by real onnxruntime from tiny
models, with degenerate candidates beside a good one (zero width, zero height, at the border, outside the frame, in
the letterbox's padding, not a number). Each degenerate one is sent sanely or dropped and counted; the good one
always goes out, in polygons and in RLE."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest

from netapp.models import Detector, DetectorConfig
from netapp.models.tasks import DETECTION_FAILED, finish
from netapp.results import bound_detections
from tests.support.onnx_models import (
    dfine_model,
    end2end_model,
    obb_model,
    rfdetr_model,
    rtdetr_model,
    yolov5_model,
    yolov8_model,
    yolov8_pose_model,
    yolov8_seg_model,
    yolox_model,
)

BOX = (8.0, 16.0, 40.0, 48.0)  # input pixels of the 64x64 models
FRAME = np.full((96, 128, 3), 80, np.uint8)  # letterboxed: 8 px of padding above and below
NAN = float("nan")
# x1, y1, x2, y2 in input pixels
DEGENERATE = [
    (20.0, 20.0, 20.0, 40.0),  # zero width
    (20.0, 30.0, 50.0, 30.0),  # zero height
    (0.0, 8.0, 64.0, 56.0),  # the whole frame, at its border
    (60.0, 52.0, 64.0, 56.0),  # in the corner
    (2.0, 0.0, 30.0, 7.0),  # in the letterbox's padding: outside the frame
    (-50.0, -50.0, -10.0, -10.0),  # outside the input
    (80.0, 80.0, 120.0, 120.0),
    (NAN, 10.0, 20.0, 30.0),  # not a number
]

BUILDERS = {
    "yolox": lambda p: yolox_model(p, BOX, 1),
    "yolov5": lambda p: yolov5_model(p, BOX, 1),
    "yolov8": lambda p: yolov8_model(p, BOX, 1),
    "end2end": lambda p: end2end_model(p, [(*BOX, 0.8, 2)]),
    "rtdetr": lambda p: rtdetr_model(p, BOX, 2),
    "rfdetr": lambda p: rfdetr_model(p, BOX, 3),
    "dfine": lambda p: dfine_model(p, BOX, 2),
    "segment-polygons": lambda p: yolov8_seg_model(p, BOX),
    "segment-rle": lambda p: yolov8_seg_model(p, BOX),
    "pose": lambda p: yolov8_pose_model(p, BOX),
    "obb": lambda p: obb_model(p, (24.0, 32.0, 16.0, 8.0, 0.3), 1),
}


def with_degenerate(found, task: str):
    """The family's own candidates, and after them the degenerate ones (scored lower than the good one)."""
    boxes = np.asarray(DEGENERATE, np.float32)
    if task == "obb":  # cx, cy, w, h, angle
        boxes = np.concatenate(((boxes[:, :2] + boxes[:, 2:]) / 2, boxes[:, 2:] - boxes[:, :2], np.ones((8, 1))), 1)
        boxes[-2, 4] = np.inf
    n = len(boxes)
    found.boxes = np.concatenate((found.boxes, boxes.astype(found.boxes.dtype)))
    found.scores = np.concatenate((found.scores, np.linspace(0.6, 0.4, n).astype(found.scores.dtype)))
    found.class_ids = np.concatenate((found.class_ids, np.full(n, found.class_ids[0], found.class_ids.dtype)))
    if found.extra is not None:
        # for a mask, the good one's coefficients negated: the mask is everywhere but the good box (so it is not
        # empty where the degenerate boxes are); for keypoints, the good one's, one of them not a number
        extra = np.repeat(found.extra[:1] * (-1 if task == "segment" else 1), n, axis=0)
        if task == "pose":
            extra[3, 0] = NAN
        found.extra = np.concatenate((found.extra, extra))
    return found


@pytest.mark.parametrize("name", list(BUILDERS))
def test_degenerate_detections_never_cost_the_frame(tmp_path, name):
    fmt = "rle" if name == "segment-rle" else "polygons"
    detector = Detector(DetectorConfig(str(BUILDERS[name](tmp_path / "m.onnx")), conf=0.3, mask_format=fmt))
    detector.load()
    prepared = detector.prepare(FRAME, {})
    outputs = detector.session.run(None, prepared.feeds)
    found = detector.family.candidates([o[0] for o in outputs], detector.card, 0.3)
    found.nms = False  # every candidate is decoded, none hidden behind another by NMS
    dropped: Counter[str] = Counter()
    result = finish(
        with_degenerate(found, detector.card.task), detector.card, prepared.placement, detector.options, dropped
    )
    detections = result["detections"]
    assert detections and detections[0]["score"] > 0.6  # the good one went out, first
    for d in detections:  # what is sent is finite, and passes the netapp's own bounds untouched
        assert all(math.isfinite(v) for v in d["bbox"]), d
        assert 0 <= d["bbox"][0] <= d["bbox"][2] <= 128 and 0 <= d["bbox"][1] <= d["bbox"][3] <= 96, d
    assert bound_detections(detections)[1] == []
    if detector.card.task == "segment":
        assert all("mask" in d for d in detections)
    # the detection that is not a number (and the keypoint that is not) is dropped and counted, nothing else fails
    assert dropped[DETECTION_FAILED] >= 1


def test_the_model_processor_counts_what_it_dropped(tmp_path):
    detector = Detector(DetectorConfig(str(yolov8_seg_model(tmp_path / "m.onnx", BOX)), mask_format="rle"))
    detector.load()
    prepared = detector.prepare(FRAME, {})
    found = detector.family.candidates([o[0] for o in detector.session.run(None, prepared.feeds)], detector.card, 0.3)
    found.boxes[:, 0] = NAN
    assert finish(found, detector.card, prepared.placement, detector.options, detector.dropped)["detections"] == []
    assert detector.dropped[DETECTION_FAILED] == len(found.scores)
