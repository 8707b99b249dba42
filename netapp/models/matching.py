"""Detections of two runs over the same frame, matched by place: the overlap of two boxes, the pairs that are the
same object, and how well one run's detections agree with another's: F1 of the boxes, and for the pairs that match,
how well their masks overlap (IoU) and their keypoints agree (COCO's OKS). Pure; boxes are `[x1, y1, x2, y2]`,
masks boolean arrays of the frame, keypoints `[[x, y, score], ...]`, all in the same frame's pixels."""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from netapp.results import KEYPOINTS_FIELD, MASK_FIELD

Detection = Mapping[str, Any]


def box_iou(a: Sequence[float], b: Sequence[float]) -> float:
    """Intersection over union of two boxes (0 when they do not overlap)."""
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    if w <= 0 or h <= 0:
        return 0.0
    inter = w * h
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


def greedy_matches(
    first: Sequence[Detection],
    second: Sequence[Detection],
    min_iou: float,
    same: Callable[[Detection, Detection], bool] = lambda a, b: True,
) -> list[tuple[int, int]]:
    """Index pairs (in `first`, in `second`) of detections at the same place, each matched once, best overlap
    first; `same` says which pairs may match at all (the same class, say)."""
    pairs = sorted(
        (
            (box_iou(d["bbox"], o["bbox"]), i, j)
            for i, d in enumerate(first)
            for j, o in enumerate(second)
            if same(d, o)
        ),
        reverse=True,
    )
    used_i, used_j, out = set(), set(), []
    for overlap, i, j in pairs:
        if overlap < min_iou:
            break
        if i not in used_i and j not in used_j:
            used_i.add(i)
            used_j.add(j)
            out.append((i, j))
    return out


def same_class(a: Detection, b: Detection) -> bool:
    return a.get("class") == b.get("class")


# COCO's per-keypoint sigmas of its 17 person keypoints (cocoeval.py), and for any other skeleton one sigma for all:
# their mean (a keypoint as hard to place as COCO's average one).
COCO_SIGMAS = (0.26, 0.25, 0.25, 0.35, 0.35, 0.79, 0.79, 0.72, 0.72, 0.62, 0.62, 1.07, 1.07, 0.87, 0.87, 0.89, 0.89)
COCO_SIGMAS = tuple(s / 10 for s in COCO_SIGMAS)
UNIFORM_SIGMA = sum(COCO_SIGMAS) / len(COCO_SIGMAS)
VISIBLE_SCORE = 0.5  # a reference keypoint counts in OKS when its score is at least this (it is "labelled")


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boolean masks of the same frame (1.0 when both are empty)."""
    union = np.count_nonzero(a | b)
    return 1.0 if union == 0 else np.count_nonzero(a & b) / union


def keypoint_similarity(
    reference: Sequence[Sequence[float]], candidate: Sequence[Sequence[float]], area: float
) -> float | None:
    """COCO's object keypoint similarity of `candidate`'s keypoints to `reference`'s, for an object of `area` square
    pixels: the mean over the reference's visible keypoints of exp(-d^2 / (2 area (2 sigma)^2)). COCO's sigmas for
    17 keypoints, `UNIFORM_SIGMA` for any other count; None when the reference has no visible keypoint or the two
    skeletons differ in length."""
    if len(reference) != len(candidate) or not reference:
        return None
    sigmas = COCO_SIGMAS if len(reference) == len(COCO_SIGMAS) else (UNIFORM_SIGMA,) * len(reference)
    total, visible = 0.0, 0
    for (rx, ry, score), (cx, cy, _), sigma in zip(reference, candidate, sigmas, strict=True):
        if score < VISIBLE_SCORE:
            continue
        visible += 1
        total += math.exp(-((rx - cx) ** 2 + (ry - cy) ** 2) / (2 * max(area, 1.0) * (2 * sigma) ** 2))
    return total / visible if visible else None


@dataclass(frozen=True)
class FrameAgreement:
    """One frame's two runs compared: boxes matched, found (candidate) and expected (reference), and for the
    matched pairs that carry them, their masks' IoU and their keypoints' OKS."""

    matched: int
    found: int
    expected: int
    mask_ious: tuple[float, ...] = ()
    oks: tuple[float, ...] = ()


def frame_agreement(
    reference: Sequence[Detection], candidate: Sequence[Detection], min_iou: float = 0.5
) -> FrameAgreement:
    """`candidate`'s detections against `reference`'s in one frame: a candidate box counts when it overlaps a
    reference box of the same class by `min_iou` or more, each matched once. Masks (boolean arrays of the frame
    under "mask") and keypoints are compared for the matched pairs where both have them."""
    pairs = greedy_matches(reference, candidate, min_iou, same_class)
    ious, oks = [], []
    for i, j in pairs:
        ref, cand = reference[i], candidate[j]
        if isinstance(ref.get(MASK_FIELD), np.ndarray) and isinstance(cand.get(MASK_FIELD), np.ndarray):
            ious.append(mask_iou(ref[MASK_FIELD], cand[MASK_FIELD]))
        if ref.get(KEYPOINTS_FIELD) and cand.get(KEYPOINTS_FIELD):
            x1, y1, x2, y2 = ref["bbox"]
            similarity = keypoint_similarity(ref[KEYPOINTS_FIELD], cand[KEYPOINTS_FIELD], (x2 - x1) * (y2 - y1))
            if similarity is not None:
                oks.append(similarity)
    return FrameAgreement(len(pairs), len(candidate), len(reference), tuple(ious), tuple(oks))


@dataclass(frozen=True)
class Agreement:
    """Over many frames: F1 of the boxes, and the mean mask IoU and OKS of the matched pairs (None: none had any)."""

    f1: float
    mask_iou: float | None = None
    oks: float | None = None


def agreement(frames: Sequence[FrameAgreement]) -> Agreement:
    """The frames' comparisons summed up. F1 is 1.0 when neither run found anything."""
    matched = sum(f.matched for f in frames)
    total = sum(f.found + f.expected for f in frames)
    ious = [v for f in frames for v in f.mask_ious]
    oks = [v for f in frames for v in f.oks]
    return Agreement(
        1.0 if total == 0 else 2 * matched / total,
        statistics.fmean(ious) if ious else None,
        statistics.fmean(oks) if oks else None,
    )


def agreement_f1(
    reference: Sequence[Sequence[Detection]], candidate: Sequence[Sequence[Detection]], min_iou: float = 0.5
) -> float:
    """F1 of `candidate`'s detections against `reference`'s over the same frames (one list per frame), as
    `frame_agreement` matches them. 1.0 when neither found anything."""
    frames = [frame_agreement(ref, cand, min_iou) for ref, cand in zip(reference, candidate, strict=True)]
    return agreement(frames).f1
