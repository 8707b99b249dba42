"""Detections of two runs over the same frame, matched by place: the overlap of two boxes, the pairs that are the
same object, and how well one run's detections agree with another's: F1 of the boxes, and for the pairs that match,
how well their masks overlap (IoU) and their keypoints agree (COCO's OKS). Pure; each run's detections are a
`netapp.detections.Detections` (or the wire list, read leniently), all in the same frame's pixels."""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from netapp.detections import Detections, as_detections

Same = Callable[[Detections, Detections], np.ndarray]  # which pairs (N x M booleans) may match at all


def box_iou(a: Sequence[float], b: Sequence[float]) -> float:
    """Intersection over union of two boxes `[x1, y1, x2, y2]` (0 when they do not overlap)."""
    return float(box_ious(np.asarray([a], np.float64), np.asarray([b], np.float64))[0, 0])


def box_ious(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """N x M intersections over union of N boxes and M boxes (xyxy rows)."""
    w = np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0])
    h = np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1])
    inter = np.where((w > 0) & (h > 0), w * h, 0.0)
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(inter > 0, inter / (area_a[:, None] + area_b[None, :] - inter), 0.0)


def greedy_matches(
    first: Detections | Sequence[Any], second: Detections | Sequence[Any], min_iou: float, same: Same | None = None
) -> list[tuple[int, int]]:
    """Index pairs (in `first`, in `second`) of detections at the same place, each matched once, best overlap
    first; `same` says which pairs may match at all (`same_class`, say)."""
    a, b = as_detections(first), as_detections(second)
    overlaps = box_ious(a.xyxy, b.xyxy)
    allowed = overlaps >= min_iou
    if same is not None:
        allowed &= same(a, b)
    rows, cols = np.nonzero(allowed)
    # best overlap first; ties in the order (i, j) descending, as sorting (overlap, i, j) in reverse gave them
    order = np.lexsort((-cols, -rows, -overlaps[rows, cols]))
    used_i, used_j, out = set(), set(), []
    for i, j in zip(rows[order].tolist(), cols[order].tolist(), strict=True):
        if i not in used_i and j not in used_j:
            used_i.add(i)
            used_j.add(j)
            out.append((i, j))
    return out


def same_class(a: Detections | Any, b: Detections | Any) -> np.ndarray:
    """Which pairs of `a` and `b` are of the same class (N x M booleans); one wire detection each gives 1 x 1."""
    a, b = (as_detections([x] if isinstance(x, Mapping) else x) for x in (a, b))
    return a.class_id[:, None] == b.class_id[None, :]


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
    if len(reference) != len(candidate) or len(reference) == 0:
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
    reference: Detections | Sequence[Any],
    candidate: Detections | Sequence[Any],
    min_iou: float = 0.5,
    frame_size: tuple[int, int] | None = None,
) -> FrameAgreement:
    """`candidate`'s detections against `reference`'s in one frame: a candidate box counts when it overlaps a
    reference box of the same class by `min_iou` or more, each matched once. Masks and keypoints are compared for
    the matched pairs where both have them; a wire mask is decoded only for a matched pair, and only with the
    frame's `frame_size` (width, height) (masks handed in decoded need none)."""
    ref, cand = as_detections(reference), as_detections(candidate)
    pairs = greedy_matches(ref, cand, min_iou, same_class)
    ious, oks = [], []
    ref_points, cand_points = ref.has_keypoints(), cand.has_keypoints()
    for i, j in pairs:
        masks = _mask_pair(ref, cand, i, j, frame_size)
        if masks is not None:
            ious.append(mask_iou(*masks))
        if ref_points[i] and cand_points[j]:
            x1, y1, x2, y2 = ref.xyxy[i]
            similarity = keypoint_similarity(ref.keypoints[i], cand.keypoints[j], (x2 - x1) * (y2 - y1))  # type: ignore[index]
            if similarity is not None:
                oks.append(similarity)
    return FrameAgreement(len(pairs), len(cand), len(ref), tuple(ious), tuple(oks))


def _mask_pair(
    ref: Detections, cand: Detections, i: int, j: int, frame_size: tuple[int, int] | None
) -> tuple[np.ndarray, np.ndarray] | None:
    """The two masks of a matched pair as boolean arrays of the frame; None when either has none, or when a wire mask
    would need the frame's size and it is not known."""
    first, second = ref.masks[i], cand.masks[j]
    if first is None or second is None:
        return None
    if frame_size is None and not (isinstance(first, np.ndarray) and isinstance(second, np.ndarray)):
        return None
    width, height = frame_size or first.shape[::-1]
    return ref.mask_array(i, height, width), cand.mask_array(j, height, width)  # type: ignore[return-value]


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
    reference: Sequence[Detections | Sequence[Any]],
    candidate: Sequence[Detections | Sequence[Any]],
    min_iou: float = 0.5,
) -> float:
    """F1 of `candidate`'s detections against `reference`'s over the same frames (one list per frame), as
    `frame_agreement` matches them. 1.0 when neither found anything."""
    frames = [frame_agreement(ref, cand, min_iou) for ref, cand in zip(reference, candidate, strict=True)]
    return agreement(frames).f1
