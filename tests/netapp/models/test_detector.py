"""The detector: each export layout decoded exactly, class names, clear errors, real detection on dog.jpg."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from netapp.models import Detector, DetectorConfig
from netapp.models.card import ModelRefused, Tensor
from netapp.models.families import recognise
from netapp.models.families.base import Signature
from netapp.models.layouts import anchor_count
from netapp.models.metadata import read_metadata
from tests.support.onnx_models import not_a_detector, yolov5_model, yolov8_model, yolox_model

BOX = (8.0, 16.0, 40.0, 48.0)  # model-input pixels of the 64x64 tiny models


def original_box(box, width, height, center):
    """Where BOX lands in an image of width x height letterboxed into 64x64."""
    ratio = min(64 / height, 64 / width)
    pad_x = (64 - round(width * ratio)) / 2 if center else 0
    pad_y = (64 - round(height * ratio)) / 2 if center else 0
    x1, y1, x2, y2 = box
    return [(x1 - pad_x) / ratio, (y1 - pad_y) / ratio, (x2 - pad_x) / ratio, (y2 - pad_y) / ratio]


@pytest.mark.parametrize(
    ("build", "layout", "center", "score"),
    [
        (yolox_model, "yolox", False, 0.81),
        (yolov5_model, "yolov5", True, 0.81),
        (yolov8_model, "ultralytics", True, 0.85),
    ],
)
def test_each_layout_decodes_to_the_original_pixels(tmp_path, build, layout, center, score):
    path = build(tmp_path / f"{layout}.onnx", BOX, class_id=1)
    detector = Detector(DetectorConfig(str(path)))
    detector.load()
    assert (detector.card.family, detector.card.task) == (layout, "detect")
    image = np.full((96, 128, 3), 80, np.uint8)  # 4:3, so the letterbox pads and the mapping matters
    detections = detector.detect(image)
    assert len(detections) == 1, detections  # yolov5's near-duplicate removed by NMS
    (d,) = detections
    assert d["class"] == 1 and d["class_name"] == "class_1"  # 3 classes, no names: generic names
    assert d["score"] == pytest.approx(score, abs=1e-3)
    expected = original_box(BOX, 128, 96, center)
    expected = [min(max(v, 0), lim) for v, lim in zip(expected, (128, 96, 128, 96), strict=True)]
    assert d["bbox"] == pytest.approx(expected, abs=0.6)


def shapes_only(*outputs: tuple, input_hw=(416, 416), task=None) -> Signature:
    """A model known by its output shapes alone (no metadata)."""
    tensors = tuple(Tensor(f"output{i}", shape) for i, shape in enumerate(outputs))
    image = (Tensor("images", (1, 3, *input_hw)),)
    return Signature(image, tensors, read_metadata({}), input_hw, task=task)


def test_families_by_shape_alone():
    a = anchor_count((416, 416))
    assert a == 3549
    assert recognise(shapes_only((1, a, 85)))[1].family == "yolox"
    assert recognise(shapes_only((1, 3 * a, 85)))[1].family == "yolov5"
    assert recognise(shapes_only((1, 84, a)))[1].family == "ultralytics"
    assert recognise(shapes_only((1, 116, a), (1, 32, 104, 104)))[1].task == "segment"
    assert recognise(shapes_only((1, 3 * a, 117), (1, 32, 104, 104)))[1].task == "segment"
    assert recognise(shapes_only((1, 300, 6)))[1].family == "end2end"
    assert recognise(shapes_only((1, 300, 84)))[1].family == "rtdetr"
    assert recognise(shapes_only((1, 1000)))[1].task == "classify"
    pose = recognise(shapes_only((1, 4 + 1 + 51, a), task="pose"))[1]
    assert (pose.task, pose.num_classes, pose.keypoints) == ("pose", 1, (17, 3))
    obb = recognise(shapes_only((1, 4 + 15 + 1, a), task="obb"))[1]
    assert (obb.task, obb.num_classes) == ("obb", 15)
    with pytest.raises(
        ModelRefused, match=r"outputs output0 \[1, 5000, 85\] .* match no known family .*known: .*YOLOX"
    ):
        recognise(shapes_only((1, 5000, 85)))
    with pytest.raises(ModelRefused, match="--layout nope is not a family"):
        recognise(shapes_only((1, a, 85)), layout="nope")


def test_class_names_from_metadata_labels_file_or_mismatch(tmp_path):
    meta = yolov8_model(tmp_path / "m.onnx", BOX, 2, metadata={"names": "{0: 'a', 1: 'b', 2: 'robot'}"})
    detector = Detector(DetectorConfig(str(meta)))
    detector.load()
    assert detector.detect(np.zeros((64, 64, 3), np.uint8))[0]["class_name"] == "robot"

    labels = tmp_path / "labels.txt"
    labels.write_text("# my classes\nx\ny\nz\n")
    detector = Detector(DetectorConfig(str(meta), labels_path=str(labels)))
    detector.load()
    assert detector.class_names == ["x", "y", "z"]

    labels.write_text("only\ntwo\n")
    with pytest.raises(ValueError, match="--labels gives 2 classes but its outputs .* hold 3 classes"):
        Detector(DetectorConfig(str(meta), labels_path=str(labels))).load()


def test_clear_errors_for_models_we_cannot_use(tmp_path):
    classifier = not_a_detector(tmp_path / "cls.onnx")  # a (1, 10) output: a classifier, unless told otherwise
    with pytest.raises(ValueError, match="match no known family for --task detect"):
        Detector(DetectorConfig(str(classifier), task="detect")).load()
    garbage = tmp_path / "garbage.onnx"
    garbage.write_bytes(b"this is not a model")
    with pytest.raises(ValueError, match="is not an ONNX model: it is text"):
        Detector(DetectorConfig(str(garbage))).load()


def test_threshold_filters_detections(tmp_path):
    path = yolox_model(tmp_path / "x.onnx", BOX, class_id=0)
    detector = Detector(DetectorConfig(str(path), conf=0.9))
    detector.load()
    assert detector.detect(np.zeros((64, 64, 3), np.uint8)) == []


def test_real_yolox_nano_finds_dog_bicycle_and_car(real_model_path, media_dir):
    detector = Detector(DetectorConfig(str(real_model_path)))
    detector.load()
    assert detector.card.family == "yolox" and detector.input_hw == (416, 416)
    detections = detector.detect(cv2.imread(str(media_dir / "dog.jpg")))
    best = {}
    for d in detections:
        best[d["class_name"]] = max(best.get(d["class_name"], 0), d["score"])
    for name in ("dog", "bicycle", "car"):
        assert best.get(name, 0) >= 0.75, detections
    dog = next(d for d in detections if d["class_name"] == "dog")
    x1, y1, x2, y2 = dog["bbox"]
    assert 100 < x1 < 170 and 180 < y1 < 240 and 290 < x2 < 360 and 510 < y2 < 576  # the dog, lower left


@pytest.mark.parametrize(
    "task, layout, advice",
    [
        (None, None, "give --task and --layout, or re-export"),
        ("detect", None, "give --layout (one of ultralytics, "),
        (None, "ultralytics", "give --task, or another --layout, or re-export"),
        ("detect", "ultralytics", "this is not a ultralytics detect export; `netapp model inspect MODEL` shows"),
    ],
)
def test_the_unknown_layout_error_never_asks_again_for_the_flags_given(real_model_path, task, layout, advice):
    """YOLOX-Nano (onnxruntime, the real file) read with the flags given: the advice follows what was given."""
    from netapp.models.families import what_to_give

    assert what_to_give(task, layout).startswith(advice)
    if layout is None:
        return  # YOLOX-Nano is recognised without one
    with pytest.raises(ModelRefused) as refused:
        Detector(DetectorConfig(str(real_model_path), task=task, layout=layout)).load()
    said = str(refused.value)
    assert said.endswith(what_to_give(task, layout)) and "match the ultralytics layout" in said, said
    if task:
        assert "give --task" not in said and "give --layout" not in said
