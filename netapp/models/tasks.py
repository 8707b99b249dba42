"""The last step of every family, per task: candidates (input pixels) -> the result's detections or
classifications (frame pixels, `netapp/results.py`'s wire form). Pure."""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable
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

log = logging.getLogger(__name__)

DETECTION_FAILED = "detection_failed"  # the reason a detection dropped by decoding is counted under
_warned: list[bool] = []


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


def finish(
    found: Candidates,
    card: ModelCard,
    placement: Placement,
    options: DecodeOptions,
    dropped: Counter[str] | None = None,
) -> dict[str, Any]:
    """One frame's result fields: `detections` (and `classifications` for a classifier). A detection whose decoding
    fails (or gives a number that is not finite) is left out and counted in `dropped`; the others still go."""
    if card.task == "classify":
        assert found.probs is not None
        probs = probabilities(found.probs)
        best = top_k(probs, options.top_k)
        classes = [Classification(int(i), card.classes[int(i)], float(probs[i])) for i in best]
        return {DETECTIONS_FIELD: [], CLASSIFICATIONS_FIELD: [c.to_wire() for c in classes]}
    return {DETECTIONS_FIELD: [d.to_wire() for d in detections(found, card, placement, options, dropped)]}


def select(found: Candidates, card: ModelCard, options: DecodeOptions) -> np.ndarray:
    """Indices of the candidates kept, best first: NMS (rotated for oriented boxes), or the best rows for exports
    that need none."""
    if not found.nms:
        return np.argsort(-found.scores, kind="stable")[: options.max_detections]  # the export's order for ties
    if card.task == "obb":
        return rotated_nms(found.boxes, found.scores, found.class_ids, options.iou, options.max_detections)
    return nms(found.boxes, found.scores, found.class_ids, options.iou, options.max_detections)


def detections(
    found: Candidates,
    card: ModelCard,
    placement: Placement,
    options: DecodeOptions,
    dropped: Counter[str] | None = None,
) -> list[Detection]:
    """The kept detections, best first, with their masks, keypoints or oriented boxes in frame pixels. Each is
    finished on its own (`_each`): one that fails is dropped and counted in `dropped`, never the whole frame."""
    if len(found.scores) == 0:
        return []
    keep = select(found, card, options)
    scores, class_ids = found.scores[keep], found.class_ids[keep].astype(np.int64)
    extra = found.extra[keep] if found.extra is not None else None
    names = card.classes
    failed: Counter[str] = dropped if dropped is not None else Counter()
    if card.task == "obb":
        rboxes = rboxes_to_frame(found.boxes[keep], placement)  # the head's angle as it is, as Ultralytics sends it
        # the enclosing box, clipped to the frame: what a 5G-ERA robot draws
        boxes = np.clip(corners_box(rbox_corners(rboxes)), 0, [placement.width, placement.height] * 2)
        return _each(
            len(keep),
            failed,
            lambda i: Detection(boxes[i], scores[i], class_ids[i], names[class_ids[i]], rbox=rboxes[i]),
        )
    input_boxes = found.boxes[keep]
    boxes = placement.boxes_to_frame(input_boxes)
    if card.task == "segment" and extra is not None and found.protos is not None:
        protos = found.protos

        def masked(i: int) -> Detection | None:
            detection = Detection(boxes[i], scores[i], class_ids[i], names[class_ids[i]])
            return _with_mask(detection, extra[i], protos, input_boxes[i], placement, card, options)

        return _each(len(keep), failed, masked)
    if card.task == "pose" and extra is not None and card.keypoints:
        count, dims = card.keypoints

        def posed(i: int) -> Detection:
            points = extra[i].reshape(count, dims)
            xy = placement.points_to_frame(points[:, :2])
            visible = points[:, 2] if dims >= 3 else np.ones(count, np.float32)
            keypoints = np.concatenate((xy, visible[:, None]), axis=1)
            return Detection(boxes[i], scores[i], class_ids[i], names[class_ids[i]], keypoints=keypoints)

        return _each(len(keep), failed, posed)
    return _each(len(keep), failed, lambda i: Detection(boxes[i], scores[i], class_ids[i], names[class_ids[i]]))


def _each(count: int, failed: Counter[str], make: Callable[[int], Detection | None]) -> list[Detection]:
    """`make(i)` for each kept detection, in order: None (nothing to send, as an empty mask) is left out; one that
    raises, or whose numbers are not all finite, is left out and counted in `failed` (its first failure logged)."""
    out = []
    for i in range(count):
        try:
            detection = make(i)
            if detection is not None and not _finite(detection):
                raise ValueError(f"a number that is not finite in {detection.bbox}")
        except Exception as exc:  # one detection's edge case (a degenerate box, a bad number) costs only itself
            if not _warned:  # once a process: a model that fails often would fill the log
                _warned.append(True)
                log.warning(
                    "a detection could not be decoded and was dropped (%r); the rest of the result is sent", exc
                )
            failed[DETECTION_FAILED] += 1
            continue
        if detection is not None:
            out.append(detection)
    return out


def _finite(detection: Detection) -> bool:
    values = [detection.bbox, [detection.score]]
    if detection.keypoints is not None:
        values.append(np.asarray(detection.keypoints, np.float64).reshape(-1))
    if detection.rbox is not None:
        values.append(detection.rbox)
    return all(np.isfinite(np.asarray(v, np.float64)).all() for v in values)


def corners_box(corners: np.ndarray) -> np.ndarray:
    """N x 4 x 2 corners -> the N x 4 axis-aligned boxes around them."""
    return np.concatenate((corners.min(axis=1), corners.max(axis=1)), axis=1)


def _with_mask(
    detection: Detection,
    coefficients: np.ndarray,
    protos: np.ndarray,
    box: np.ndarray,
    placement: Placement,
    card: ModelCard,
    options: DecodeOptions,
) -> Detection | None:
    """A detection with its mask; None when the mask is empty (in the model's input or in the frame), as Ultralytics
    drops such a detection. Polygons are traced at the model's resolution (the mask's own) and moved to the frame;
    an RLE is the frame-sized mask."""
    mask, x0, y0 = mask_in_box(coefficients, protos, box, card.pixels.size_hw)
    if not mask.any():
        return None
    if options.mask_format == "rle":
        inside, fx0, fy0 = mask_to_frame(mask, x0, y0, placement)
        if not inside.any():  # the mask falls outside the frame (a box at or past its border)
            return None
        detection.mask = Mask(rle=region_rle(inside, fx0, fy0, placement.height, placement.width))
    else:
        traced = Mask.from_array(mask, origin=(x0, y0))
        detection.mask = Mask(polygons=polygons_to_frame(traced.polygons or [], placement))
    return detection
