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
    return constant_model(path, {"output": output}, input_hw, metadata)


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


# --- the other families and tasks, as their exporters lay them out (netapp/models/families) ----------------------


def constant_model(
    path: Path,
    outputs: dict[str, np.ndarray],
    input_hw: tuple[int, int] = (64, 64),
    metadata: dict[str, str] | None = None,
    input_name: str = "images",
    target_sizes: bool = False,
) -> Path:
    """A graph whose outputs are the given arrays (floats + 0 * mean(input), so the image is consumed; integers as
    they are), with D-FINE's `orig_target_sizes` input when asked."""
    h, w = input_hw
    inits = [numpy_helper.from_array(np.zeros((), np.float32), "zero")]
    nodes = [
        helper.make_node("ReduceMean", [input_name], ["mean"], keepdims=0),
        helper.make_node("Mul", ["mean", "zero"], ["nothing"]),
    ]
    outs = []
    for name, value in outputs.items():
        integer = np.issubdtype(value.dtype, np.integer)
        value = value.astype(np.int64 if integer else np.float32)
        inits.append(numpy_helper.from_array(value, f"{name}_const"))
        if integer:
            nodes.append(helper.make_node("Identity", [f"{name}_const"], [name]))
        else:
            nodes.append(helper.make_node("Add", [f"{name}_const", "nothing"], [name]))
        kind = TensorProto.INT64 if integer else TensorProto.FLOAT
        outs.append(helper.make_tensor_value_info(name, kind, list(value.shape)))
    inputs = [helper.make_tensor_value_info(input_name, TensorProto.FLOAT, [1, 3, h, w])]
    if target_sizes:
        inputs.append(helper.make_tensor_value_info("orig_target_sizes", TensorProto.INT64, [1, 2]))
    graph = helper.make_graph(nodes, "tiny", inputs, outs, inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    for key, value in (metadata or {}).items():
        model.metadata_props.append(onnx.StringStringEntryProto(key=key, value=value))
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def ultralytics_metadata(task: str, names: list[str], input_hw=(64, 64), **extra: str) -> dict[str, str]:
    """Metadata as Ultralytics writes it: Python reprs."""
    return {"task": task, "names": str(dict(enumerate(names))), "imgsz": str(list(input_hw)), "stride": "32", **extra}


def rect_prototypes(box_xyxy: tuple[float, ...], input_hw=(64, 64), channels: int = 32) -> np.ndarray:
    """(1, 32, H/4, W/4) prototypes whose first channel is +4 inside the box (input pixels) and -4 outside: with
    coefficients (1, 0, ...), the mask is the box."""
    ph, pw = input_hw[0] // 4, input_hw[1] // 4
    protos = np.zeros((1, channels, ph, pw), np.float32)
    protos[0, 0] = -4.0
    x1, y1, x2, y2 = (int(round(v / 4)) for v in box_xyxy)
    protos[0, 0, y1:y2, x1:x2] = 4.0
    return protos


def yolov8_seg_model(path: Path, box_xyxy: tuple[float, ...], input_hw=(64, 64), with_metadata: bool = True) -> Path:
    """A one-class YOLOv8-seg export finding one object whose mask fills its box."""
    anchors = anchor_count(input_hw)
    out = np.zeros((1, 4 + 1 + 32, anchors), np.float32)
    x1, y1, x2, y2 = box_xyxy
    out[0, :4, 5] = ((x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1)
    out[0, 4, 5] = 0.9
    out[0, 5, 5] = 1.0  # the first mask coefficient
    metadata = ultralytics_metadata("segment", ["blob"], input_hw) if with_metadata else None
    outputs = {"output0": out, "output1": rect_prototypes(box_xyxy, input_hw)}
    return constant_model(path, outputs, input_hw, metadata)


POSE_POINTS = [(10.0 + 2 * k, 20.0 + k, 0.9) for k in range(17)]  # input pixels, visibility


def yolov8_pose_model(path: Path, box_xyxy: tuple[float, ...], input_hw=(64, 64)) -> Path:
    """A one-class YOLOv8-pose export (kpt_shape [17, 3]) finding one person with POSE_POINTS."""
    anchors = anchor_count(input_hw)
    out = np.zeros((1, 4 + 1 + 51, anchors), np.float32)
    x1, y1, x2, y2 = box_xyxy
    out[0, :4, 5] = ((x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1)
    out[0, 4, 5] = 0.9
    out[0, 5:, 5] = np.asarray(POSE_POINTS, np.float32).reshape(-1)
    metadata = ultralytics_metadata("pose", ["person"], input_hw, kpt_shape="[17, 3]")
    return constant_model(path, {"output0": out}, input_hw, metadata)


def end2end_model(path: Path, rows: list[tuple[float, ...]], input_hw=(64, 64), n: int = 300, **meta) -> Path:
    """A YOLOv10 / YOLO26 end-to-end export: (1, N, 6) rows of x1, y1, x2, y2, score, class, best first."""
    out = np.zeros((1, n, 6), np.float32)
    if rows:
        out[0, : len(rows)] = rows
    return constant_model(path, {"output0": out}, input_hw, meta or None)


def rtdetr_model(
    path: Path, box_xyxy: tuple[float, ...], class_id: int, num_classes: int = 3, input_hw=(64, 64)
) -> Path:
    """An Ultralytics RT-DETR export: (1, 300, 4+C) normalised cx, cy, w, h and class scores; head RTDETRDecoder."""
    h, w = input_hw
    out = np.zeros((1, 300, 4 + num_classes), np.float32)
    x1, y1, x2, y2 = box_xyxy
    out[0, 7, :4] = ((x1 + x2) / 2 / w, (y1 + y2) / 2 / h, (x2 - x1) / w, (y2 - y1) / h)
    out[0, 7, 4 + class_id] = 0.8
    names = [f"c{i}" for i in range(num_classes)]
    metadata = ultralytics_metadata("detect", names, input_hw, head="RTDETRDecoder", end2end="False")
    return constant_model(path, {"output0": out}, input_hw, metadata)


def rfdetr_model(
    path: Path, box_xyxy: tuple[float, ...], class_id: int, num_classes: int = 91, input_hw=(64, 64)
) -> Path:
    """An RF-DETR export: input `input`, outputs dets (1, 300, 4) normalised cxcywh and labels (1, 300, C) logits."""
    h, w = input_hw
    dets = np.full((1, 300, 4), 0.5, np.float32)
    labels = np.full((1, 300, num_classes), -10.0, np.float32)
    x1, y1, x2, y2 = box_xyxy
    dets[0, 11] = ((x1 + x2) / 2 / w, (y1 + y2) / 2 / h, (x2 - x1) / w, (y2 - y1) / h)
    labels[0, 11, class_id] = 2.0  # sigmoid 0.88
    return constant_model(path, {"dets": dets, "labels": labels}, input_hw, input_name="input")


def dfine_model(path: Path, box_xyxy: tuple[float, ...], class_id: int, input_hw=(64, 64)) -> Path:
    """A D-FINE export: inputs images + orig_target_sizes, outputs labels, boxes (x1, y1, x2, y2 in the target
    size; the netapp gives the input's own), scores."""
    labels = np.zeros((1, 300), np.int64)
    boxes = np.zeros((1, 300, 4), np.float32)
    scores = np.zeros((1, 300), np.float32)
    labels[0, 0], boxes[0, 0], scores[0, 0] = class_id, box_xyxy, 0.7
    outputs = {"labels": labels, "boxes": boxes, "scores": scores}
    return constant_model(path, outputs, input_hw, target_sizes=True)


def many_candidates_model(path: Path, count: int = 1000, input_hw=(256, 256)) -> Path:
    """A YOLOv8 export (2 classes) with `count` candidates over the threshold, many overlapping, the best of them
    degenerate (no area)."""
    anchors = anchor_count(input_hw)
    assert count <= anchors
    rng = np.random.default_rng(0)
    out = np.zeros((1, 4 + 2, anchors), np.float32)
    out[0, 0:2, :count] = rng.uniform(8, input_hw[1] - 8, (2, count))
    out[0, 2:4, :count] = rng.uniform(4, 40, (2, count))
    out[0, 2:4, 0] = 0.0  # the degenerate box, and the best
    out[0, 4 + (np.arange(count) % 2), np.arange(count)] = rng.uniform(0.3, 0.9, count)
    out[0, 4, 0] = 0.95
    return constant_model(path, {"output0": out}, input_hw)


def classifier_model(path: Path, scores: list[float], input_hw=(32, 32)) -> Path:
    """A (1, C) classifier: these logits, or these probabilities when the graph ends in a softmax."""
    return constant_model(path, {"output0": np.asarray([scores], np.float32)}, input_hw)


def obb_model(path: Path, rbox: tuple[float, ...], class_id: int, num_classes: int = 2, input_hw=(64, 64)) -> Path:
    """A YOLO11-obb export: (1, 4+C+1, A) with the angle in radians last; metadata task obb."""
    out = np.zeros((1, 4 + num_classes + 1, anchor_count(input_hw)), np.float32)
    out[0, :4, 3] = rbox[:4]
    out[0, 4 + class_id, 3] = 0.9
    out[0, -1, 3] = rbox[4]
    metadata = ultralytics_metadata("obb", [f"c{i}" for i in range(num_classes)], input_hw)
    return constant_model(path, {"output0": out}, input_hw, metadata)


def hungry_model(path: Path, megabytes: int, input_hw=(64, 64)) -> Path:
    """A YOLOv8 detector (no candidates) whose graph tiles its input to about `megabytes` MB on every run: static
    shapes, nothing to fold at load, the memory asked for only when it runs (issue 45, row 11)."""
    h, w = input_hw
    repeats = max(1, megabytes * 2**20 // (3 * h * w * 4))
    out = np.zeros((1, 4 + 2, anchor_count(input_hw)), np.float32)
    inits = [
        numpy_helper.from_array(np.array([repeats, 1, 1, 1], np.int64), "repeats"),
        numpy_helper.from_array(np.zeros((), np.float32), "zero"),
        numpy_helper.from_array(out, "base"),
    ]
    nodes = [
        helper.make_node("Tile", ["images", "repeats"], ["big"]),
        helper.make_node("ReduceSum", ["big"], ["sum"], keepdims=0),
        helper.make_node("Mul", ["sum", "zero"], ["nothing"]),
        helper.make_node("Add", ["base", "nothing"], ["output0"]),
    ]
    graph = helper.make_graph(
        nodes,
        "hungry",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, h, w])],
        [helper.make_tensor_value_info("output0", TensorProto.FLOAT, list(out.shape))],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.save(model, str(path))
    return path


def dynamic_model(path: Path, metadata: dict[str, str]) -> Path:
    """A YOLOv8 detector whose input's height and width are symbolic (its metadata's `imgsz` names them) and whose
    output's anchors follow them, one per cell of each stride: (1, 6, A) of zeros."""
    nodes = []
    for stride in STRIDES:
        nodes.append(
            helper.make_node("AveragePool", ["images"], [f"p{stride}"], kernel_shape=[stride] * 2, strides=[stride] * 2)
        )
        nodes.append(helper.make_node("Reshape", [f"p{stride}", "shape"], [f"f{stride}"]))  # (1, 3, cells)
    nodes.append(helper.make_node("Concat", [f"f{s}" for s in STRIDES], ["anchors"], axis=2))
    nodes.append(helper.make_node("Mul", ["anchors", "zero"], ["zeros"]))
    nodes.append(helper.make_node("Concat", ["zeros", "zeros"], ["output0"], axis=1))
    graph = helper.make_graph(
        nodes,
        "dynamic",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, "height", "width"])],
        [helper.make_tensor_value_info("output0", TensorProto.FLOAT, [1, 6, "anchors"])],
        [
            numpy_helper.from_array(np.array([1, 3, -1], np.int64), "shape"),
            numpy_helper.from_array(np.zeros((), np.float32), "zero"),
        ],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    for key, value in metadata.items():
        model.metadata_props.append(onnx.StringStringEntryProto(key=key, value=value))
    onnx.save(model, str(path))
    return path
