"""Track ids of two runs over the same frames, compared by position: how a move between netapps, or anything
else, changed them. Results are lists of detections (`bbox`, `track_id`), one list per frame."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from netapp.detections import Detections, as_detections
from netapp.models.matching import greedy_matches

Frame = Detections | Sequence[Any]  # one result's detections, or the wire's list of them


def _tracked(frame: Frame) -> Detections:
    """The detections of a frame that have a track id."""
    dets = as_detections(frame)
    return dets[dets.tracker_id >= 0] if dets.tracker_id is not None else dets[np.zeros(len(dets), bool)]


def matched_ids(frame: Frame, other: Frame, min_iou: float = 0.7) -> list[tuple[int, int]]:
    """(track id in `frame`, track id in `other`) of the tracked detections at the same place in both."""
    ours, theirs = _tracked(frame), _tracked(other)
    return [(int(ours.tracker_id[i]), int(theirs.tracker_id[j])) for i, j in greedy_matches(ours, theirs, min_iou)]  # type: ignore[index]


def id_switches(frames: Sequence[Frame], min_iou: float = 0.5, memory: int = 5) -> int:
    """How often an object changed its id: a tracked detection overlapping by `min_iou` or more (the same object)
    the last tracked detection seen there, within `memory` results, under another id. Needs no ground truth; a
    few results without an id (a new tracker confirming its tracks) do not hide a switch."""
    switches = 0
    seen = _tracked([])  # the latest tracked detections
    ages = np.zeros(0, np.int64)  # and their age in results
    for frame in frames:
        tracked = _tracked(frame)
        pairs = greedy_matches(tracked, seen, min_iou)
        switches += sum(tracked.tracker_id[i] != seen.tracker_id[j] for i, j in pairs)  # type: ignore[index]
        older = np.ones(len(seen), bool)
        older[[j for _, j in pairs]] = False
        older &= ages + 1 < memory
        seen = Detections.merge([tracked, seen[older]])
        ages = np.concatenate((np.zeros(len(tracked), np.int64), ages[older] + 1))
    return switches
