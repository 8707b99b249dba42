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


def _matches(frame: Frame, other: Frame, min_iou: float) -> list[tuple[int, int]]:
    """Index pairs of the tracked detections at the same place in both, each matched once, best overlap first."""
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
            out.append((i, j))
    return out


def matched_ids(frame: Frame, other: Frame, min_iou: float = 0.7) -> list[tuple[int, int]]:
    """(track id in `frame`, track id in `other`) of the tracked detections at the same place in both."""
    return [(frame[i]["track_id"], other[j]["track_id"]) for i, j in _matches(frame, other, min_iou)]


def id_switches(frames: Sequence[Frame], min_iou: float = 0.5, memory: int = 5) -> int:
    """How often an object changed its id: a tracked detection overlapping by `min_iou` or more (the same object)
    the last tracked detection seen there, within `memory` results, under another id. Needs no ground truth; a
    few results without an id (a new tracker confirming its tracks) do not hide a switch."""
    switches = 0
    seen: list[tuple[Mapping[str, Any], int]] = []  # the latest tracked detections, with their age in results
    for frame in frames:
        tracked = [d for d in frame if d.get("track_id") is not None]
        pairs = _matches(tracked, [d for d, _ in seen], min_iou)
        switches += sum(tracked[i]["track_id"] != seen[j][0]["track_id"] for i, j in pairs)
        matched = {j for _, j in pairs}
        older = [(d, age + 1) for j, (d, age) in enumerate(seen) if j not in matched and age + 1 < memory]
        seen = [(d, 0) for d in tracked] + older
    return switches
