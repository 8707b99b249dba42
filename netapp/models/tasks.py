"""The last step of every family, per task: candidates (input pixels) -> the result's detections or
classifications (frame pixels, `netapp/results.py`'s wire form). Pure."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from netapp.models.card import ModelCard
from netapp.models.decoding import (
    mask_in_box,
    mask_to_frame,
    nms,
    polygons_to_frame,
    probabilities,
    rbox_corners,
    rboxes_to_frame,
    region_rle,
    rotated_nms,
    top_k,
)
from netapp.models.preprocess import Placement
from netapp.results import CLASSIFICATIONS_FIELD, DETECTIONS_FIELD, Classification, Detection, Mask


@dataclass(frozen=True)
class DecodeOptions:
    """What `netapp serve` asks of decoding."""

    conf: float = 0.3
    iou: float = 0.45
    max_detections: int = 300
    mask_format: str = "polygons"  # or "rle"
    top_k: int = 5  # classifications per frame


@dataclass
class Candidates:
    """A family's reading of one frame's outputs, over the score threshold, in model-input pixels.

    `boxes` are x1, y1, x2, y2 (cx, cy, w, h, angle for oriented boxes); `extra` holds each candidate's mask
    coefficients or keypoints (x, y[, score] per keypoint); `nms` is False for exports that ran it (or need none)."""

    boxes: np.ndarray
    scores: np.ndarray
    class_ids: np.ndarray
    extra: np.ndarray | None = None
    protos: np.ndarray | None = None  # segmentation: C x H x W prototypes
    nms: bool = True
    probs: np.ndarray | None = None  # classification: one score per class

    @classmethod
    def classes(cls, probs: np.ndarray) -> Candidates:
        empty = np.zeros((0, 4), np.float32)
        return cls(empty, np.zeros(0, np.float32), np.zeros(0, np.int64), probs=probs)


def finish(found: Candidates, card: ModelCard, placement: Placement, options: DecodeOptions) -> dict[str, Any]:
    """One frame's result fields: `detections` (and `classifications` for a classifier)."""
    if card.task == "classify":
        assert found.probs is not None
        probs = probabilities(found.probs)
        best = top_k(probs, options.top_k)
        classes = [Classification(int(i), card.classes[int(i)], float(probs[i])) for i in best]
        return {DETECTIONS_FIELD: [], CLASSIFICATIONS_FIELD: [c.to_wire() for c in classes]}
    return {DETECTIONS_FIELD: [d.to_wire() for d in detections(found, card, placement, options)]}


def select(found: Candidates, card: ModelCard, options: DecodeOptions) -> np.ndarray:
    """Indices of the candidates kept, best first: NMS (rotated for oriented boxes), or the best rows for exports
    that need none."""
    if not found.nms:
        return np.argsort(-found.scores, kind="stable")[: options.max_detections]  # the export's order for ties
    if card.task == "obb":
        return rotated_nms(found.boxes, found.scores, found.class_ids, options.iou, options.max_detections)
    return nms(found.boxes, found.scores, found.class_ids, options.iou, options.max_detections)


def detections(found: Candidates, card: ModelCard, placement: Placement, options: DecodeOptions) -> list[Detection]:
    """The kept detections, best first, with their masks, keypoints or oriented boxes in frame pixels."""
    if len(found.scores) == 0:
        return []
    keep = select(found, card, options)
    scores, class_ids = found.scores[keep], found.class_ids[keep].astype(np.int64)
    extra = found.extra[keep] if found.extra is not None else None
    names = card.classes
    if card.task == "obb":
        rboxes = rboxes_to_frame(found.boxes[keep], placement)  # the head's angle as it is, as Ultralytics sends it
        # the enclosing box, clipped to the frame: what a 5G-ERA robot draws
        boxes = np.clip(corners_box(rbox_corners(rboxes)), 0, [placement.width, placement.height] * 2)
        return [
            Detection(box, s, c, names[c], rbox=r)
            for box, s, c, r in zip(boxes, scores, class_ids, rboxes, strict=True)
        ]
    input_boxes = found.boxes[keep]
    boxes = placement.boxes_to_frame(input_boxes)
    out = [Detection(b, s, c, names[c]) for b, s, c in zip(boxes, scores, class_ids, strict=True)]
    if card.task == "segment" and extra is not None and found.protos is not None:
        return _with_masks(out, extra, found.protos, input_boxes, placement, card, options)
    if card.task == "pose" and extra is not None and card.keypoints:
        count, dims = card.keypoints
        points = extra.reshape(len(out), count, dims)
        xy = placement.points_to_frame(points[..., :2])
        visible = points[..., 2] if dims >= 3 else np.ones(points.shape[:2], np.float32)
        for detection, p, v in zip(out, xy, visible, strict=True):
            detection.keypoints = np.concatenate((p, v[:, None]), axis=1)
    return out


def corners_box(corners: np.ndarray) -> np.ndarray:
    """N x 4 x 2 corners -> the N x 4 axis-aligned boxes around them."""
    return np.concatenate((corners.min(axis=1), corners.max(axis=1)), axis=1)


def _with_masks(
    out: list[Detection],
    coefficients: np.ndarray,
    protos: np.ndarray,
    input_boxes: np.ndarray,
    placement: Placement,
    card: ModelCard,
    options: DecodeOptions,
) -> list[Detection]:
    """Each detection's mask; a detection whose mask is empty is dropped, as Ultralytics drops it. Polygons are
    traced at the model's resolution (the mask's own) and moved to the frame; an RLE is the frame-sized mask."""
    kept = []
    for detection, coeff, box in zip(out, coefficients, input_boxes, strict=True):
        mask, x0, y0 = mask_in_box(coeff, protos, box, card.pixels.size_hw)
        if not mask.any():
            continue
        if options.mask_format == "rle":
            inside, fx0, fy0 = mask_to_frame(mask, x0, y0, placement)
            detection.mask = Mask(rle=region_rle(inside, fx0, fy0, placement.height, placement.width))
        else:
            traced = Mask.from_array(mask, origin=(x0, y0))
            detection.mask = Mask(polygons=polygons_to_frame(traced.polygons or [], placement))
        kept.append(detection)
    return kept
