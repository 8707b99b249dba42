"""Output layouts of the YOLO-family ONNX exports, recognised from the output shape, and their pure decoders.

Every decoder returns candidate boxes (x1, y1, x2, y2 in model-input pixels), scores and class ids, before NMS.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

STRIDES = (8, 16, 32)

Decoded = tuple[np.ndarray, np.ndarray, np.ndarray]  # boxes Nx4 float32, scores N float32, class ids N int


@dataclass(frozen=True)
class Layout:
    """What a model expects and how to read what it returns."""

    name: str
    num_classes: int
    center_pad: bool  # letterbox centring
    rgb: bool
    scale: float  # pixel scale applied before inference

    def decode(self, output: np.ndarray, input_hw: tuple[int, int], conf: float) -> Decoded:
        """Candidate boxes of one image's raw output, before NMS."""
        return DECODERS[self.name](output, self.num_classes, input_hw, conf)


def grid_points(input_hw: tuple[int, int], strides: tuple[int, ...] = STRIDES) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) grid offsets and the stride of every anchor point, in YOLOX order (stride by stride, row-major)."""
    grids, expanded = [], []
    for s in strides:
        gh, gw = input_hw[0] // s, input_hw[1] // s
        ys, xs = np.meshgrid(np.arange(gh), np.arange(gw), indexing="ij")
        grids.append(np.stack((xs, ys), axis=-1).reshape(-1, 2))
        expanded.append(np.full((gh * gw, 1), s))
    return np.concatenate(grids).astype(np.float32), np.concatenate(expanded).astype(np.float32)


def anchor_count(input_hw: tuple[int, int], strides: tuple[int, ...] = STRIDES) -> int:
    return sum((input_hw[0] // s) * (input_hw[1] // s) for s in strides)


def _xywh_to_xyxy(xywh: np.ndarray) -> np.ndarray:
    half = xywh[:, 2:4] / 2
    return np.concatenate((xywh[:, :2] - half, xywh[:, :2] + half), axis=1)


def _best_class(cls_scores: np.ndarray, weight: np.ndarray | None, conf: float) -> tuple[np.ndarray, ...]:
    class_ids = cls_scores.argmax(axis=1)
    scores = cls_scores[np.arange(len(cls_scores)), class_ids]
    if weight is not None:
        scores = scores * weight
    keep = scores >= conf
    return keep, scores[keep].astype(np.float32), class_ids[keep]


def decode_yolox(output: np.ndarray, num_classes: int, input_hw: tuple[int, int], conf: float) -> Decoded:
    """YOLOX export without decode_in_inference: grid offsets and log sizes per stride; obj and cls sigmoided."""
    pred = output.reshape(-1, 5 + num_classes)
    keep, scores, class_ids = _best_class(pred[:, 5:], pred[:, 4], conf)
    grids, strides = grid_points(input_hw)
    p, g, s = pred[keep], grids[keep], strides[keep]
    xy = (p[:, :2] + g) * s
    wh = np.exp(np.minimum(p[:, 2:4], 20.0)) * s  # clamp: a wild logit must not overflow to inf
    return _xywh_to_xyxy(np.concatenate((xy, wh), axis=1)), scores, class_ids


def decode_yolov5(output: np.ndarray, num_classes: int, input_hw: tuple[int, int], conf: float) -> Decoded:
    """YOLOv5 export: rows of (cx, cy, w, h) in pixels, objectness, class scores."""
    pred = output.reshape(-1, 5 + num_classes)
    candidates = pred[pred[:, 4] >= conf]
    keep, scores, class_ids = _best_class(candidates[:, 5:], candidates[:, 4], conf)
    return _xywh_to_xyxy(candidates[keep, :4]), scores, class_ids


def decode_yolov8(output: np.ndarray, num_classes: int, input_hw: tuple[int, int], conf: float) -> Decoded:
    """YOLOv8 / YOLO11 export: (4 + classes) x anchors, boxes in pixels, no objectness."""
    pred = output.reshape(4 + num_classes, -1).T
    keep, scores, class_ids = _best_class(pred[:, 4:], None, conf)
    return _xywh_to_xyxy(pred[keep, :4]), scores, class_ids


DECODERS = {"yolox": decode_yolox, "yolov5": decode_yolov5, "yolov8": decode_yolov8}


def identify_layout(output_shape: tuple[int, ...], input_hw: tuple[int, int]) -> Layout:
    """Recognise the export from its output shape; raise ValueError with the reason when it is none we know."""
    if len(output_shape) != 3:
        raise ValueError(f"expected a 3-D detection output (batch, rows, cols), got shape {tuple(output_shape)}")
    _, rows, cols = output_shape
    anchors = anchor_count(input_hw)
    if isinstance(rows, int) and isinstance(cols, int):
        if rows == anchors and cols > 5:
            return Layout("yolox", cols - 5, center_pad=False, rgb=False, scale=1.0)
        if rows == 3 * anchors and cols > 5:
            return Layout("yolov5", cols - 5, center_pad=True, rgb=True, scale=1 / 255)
        if cols == anchors and rows > 4:
            return Layout("yolov8", rows - 4, center_pad=True, rgb=True, scale=1 / 255)
    raise ValueError(
        f"output shape {tuple(output_shape)} matches no known detector layout for input {input_hw[1]}x{input_hw[0]}: "
        f"expected YOLOX (1, {anchors}, 5+C), YOLOv5 (1, {3 * anchors}, 5+C) or YOLOv8/YOLO11 (1, 4+C, {anchors})"
    )
