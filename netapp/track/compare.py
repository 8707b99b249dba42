"""Track ids of two runs over the same frames, compared by position: how a move between netapps, or anything
else, changed them. Results are lists of detections (`bbox`, `track_id`), one list per frame."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from netapp.models.matching import greedy_matches

Frame = Sequence[Mapping[str, Any]]


def _matches(frame: Frame, other: Frame, min_iou: float) -> list[tuple[int, int]]:
    """Index pairs of the tracked detections at the same place in both, each matched once, best overlap first."""
    return greedy_matches(frame, other, min_iou, lambda d, o: _tracked(d) and _tracked(o))


def _tracked(detection: Mapping[str, Any]) -> bool:
    return detection.get("track_id") is not None


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
