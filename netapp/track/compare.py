"""Track ids of two runs over the same frames, compared by position: how a move between netapps, or anything
else, changed them. Results are lists of detections (`bbox`, `track_id`), one list per frame."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

Frame = Sequence[Mapping[str, Any]]


def box_iou(a: Sequence[float], b: Sequence[float]) -> float:
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    if w <= 0 or h <= 0:
        return 0.0
    inter = w * h
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


def matched_ids(frame: Frame, other: Frame, min_iou: float = 0.7) -> list[tuple[int, int]]:
    """(track id in `frame`, track id in `other`) of the tracked detections at the same place in both (each
    detection matched once, best overlap first)."""
    pairs = sorted(
        (
            (box_iou(d["bbox"], o["bbox"]), i, j)
            for i, d in enumerate(frame)
            if d.get("track_id") is not None
            for j, o in enumerate(other)
            if o.get("track_id") is not None
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
            out.append((frame[i]["track_id"], other[j]["track_id"]))
    return out


def id_switches(frames: Sequence[Frame], min_iou: float = 0.5) -> int:
    """How often an object changed its id from one result to the next: a tracked detection overlapping one of the
    previous result by `min_iou` or more (the same object) under another id. Needs no ground truth."""
    return sum(a != b for i in range(1, len(frames)) for a, b in matched_ids(frames[i], frames[i - 1], min_iou))
