"""Tiny ONNX detectors built by the tests: constant outputs laid out like each YOLO export, so decoding can be
checked exactly without any real weights."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from netapp.models.layouts import STRIDES, anchor_count

TINY_BOX = (8.0, 16.0, 40.0, 48.0)  # the box the tiny YOLOX model always finds, in its 64x64 input
TINY_NAMES = ["cat", "dog", "robot"]  # its classes (it finds a `robot`)


def _save(path: Path, output: np.ndarray, input_hw: tuple[int, int], metadata: dict[str, str] | None) -> Path:
    """A graph whose output is `output` + 0 * mean(input): it consumes the input, as a real detector does."""
    h, w = input_hw
    const = numpy_helper.from_array(output.astype(np.float32), "const_out")
    zero = numpy_helper.from_array(np.zeros((), np.float32), "zero")
    nodes = [
        helper.make_node("ReduceMean", ["images"], ["mean"], keepdims=0),
        helper.make_node("Mul", ["mean", "zero"], ["nothing"]),
        helper.make_node("Add", ["const_out", "nothing"], ["output"]),
    ]
    graph = helper.make_graph(
        nodes,
        "tiny",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, h, w])],
        [helper.make_tensor_value_info("output", TensorProto.FLOAT, list(output.shape))],
        [const, zero],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    for key, value in (metadata or {}).items():
        model.metadata_props.append(onnx.StringStringEntryProto(key=key, value=value))
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def yolox_model(
    path: Path,
    box_xyxy: tuple[float, ...],
    class_id: int,
    num_classes: int = 3,
    input_hw: tuple[int, int] = (64, 64),
    metadata: dict[str, str] | None = None,
) -> Path:
    """One YOLOX anchor (stride 8) predicting `box_xyxy` (model-input pixels) with score 0.9 * 0.9."""
    out = np.zeros((1, anchor_count(input_hw), 5 + num_classes), np.float32)
    x1, y1, x2, y2 = box_xyxy
    cx, cy, bw, bh = (x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1
    stride = STRIDES[0]
    gx, gy = int(cx // stride), int(cy // stride)
    row = gy * (input_hw[1] // stride) + gx
    out[0, row, :4] = (cx / stride - gx, cy / stride - gy, math.log(bw / stride), math.log(bh / stride))
    out[0, row, 4] = 0.9
    out[0, row, 5 + class_id] = 0.9
    return _save(path, out, input_hw, metadata)


def yolov5_model(
    path: Path,
    box_xyxy: tuple[float, ...],
    class_id: int,
    num_classes: int = 3,
    input_hw: tuple[int, int] = (64, 64),
    metadata: dict[str, str] | None = None,
) -> Path:
    out = np.zeros((1, 3 * anchor_count(input_hw), 5 + num_classes), np.float32)
    x1, y1, x2, y2 = box_xyxy
    out[0, 7, :5] = ((x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1, 0.9)
    out[0, 7, 5 + class_id] = 0.9
    out[0, 8, :5] = ((x1 + x2) / 2 + 1, (y1 + y2) / 2, x2 - x1, y2 - y1, 0.8)  # a near-duplicate NMS must remove
    out[0, 8, 5 + class_id] = 0.9
    return _save(path, out, input_hw, metadata)


def yolov8_model(
    path: Path,
    box_xyxy: tuple[float, ...],
    class_id: int,
    num_classes: int = 3,
    input_hw: tuple[int, int] = (64, 64),
    metadata: dict[str, str] | None = None,
) -> Path:
    out = np.zeros((1, 4 + num_classes, anchor_count(input_hw)), np.float32)
    x1, y1, x2, y2 = box_xyxy
    out[0, :4, 5] = ((x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1)
    out[0, 4 + class_id, 5] = 0.85
    return _save(path, out, input_hw, metadata)


def not_a_detector(path: Path) -> Path:
    """A model with a 2-D output: a classifier, say."""
    return _save(path, np.zeros((1, 10), np.float32), (64, 64), None)
