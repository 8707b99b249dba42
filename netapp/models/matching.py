"""Detections of two runs over the same frame, matched by place: the overlap of two boxes, the pairs that are the
same object, and how well one run's detections agree with another's (F1). Pure; boxes are `[x1, y1, x2, y2]`."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

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


def agreement_f1(
    reference: Sequence[Sequence[Detection]], candidate: Sequence[Sequence[Detection]], min_iou: float = 0.5
) -> float:
    """F1 of `candidate`'s detections against `reference`'s over the same frames (one list per frame): a candidate
    box counts when it overlaps a reference box of the same class by `min_iou` or more, each matched once. 1.0 when
    neither found anything."""
    matched = found = expected = 0
    for ref, cand in zip(reference, candidate, strict=True):
        matched += len(greedy_matches(ref, cand, min_iou, same_class))
        found += len(cand)
        expected += len(ref)
    return 1.0 if found + expected == 0 else 2 * matched / (found + expected)
