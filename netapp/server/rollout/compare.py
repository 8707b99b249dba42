"""One frame's two answers compared: the current model's result and the candidate's, as the robot would get them.
Pure; the matching itself (boxes, mask IoU, OKS) is `netapp.models.matching`'s."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from netapp.detections import Detections
from netapp.models.matching import FrameAgreement, frame_agreement
from netapp.results import CLASSIFICATIONS_FIELD

MIN_IOU = 0.5  # a candidate box matches a current box of the same class that it overlaps by this much
MAX_MASKS = 100  # past this many masks in a frame, boxes alone count (each mask compared is a frame-sized array)


def compare_results(
    current: Mapping[str, Any], candidate: Mapping[str, Any], frame_size: tuple[int, int] | None = None
) -> FrameAgreement:
    """How well `candidate`'s result agrees with `current`'s for one frame: a classifier's top-1 (1 of 1 when the
    same class), else the detections matched by class and IoU >= MIN_IOU, with mask IoU and OKS of the matched
    pairs. `frame_size` (width, height) lets masks be compared (a malformed one is compared as a box)."""
    current_top = current.get(CLASSIFICATIONS_FIELD) or []
    candidate_top = candidate.get(CLASSIFICATIONS_FIELD) or []
    if current_top or candidate_top:
        same = bool(current_top and candidate_top and current_top[0].get("class") == candidate_top[0].get("class"))
        return FrameAgreement(int(same), int(bool(candidate_top)), int(bool(current_top)))
    ours, theirs = Detections.from_wire(current, strict=False), Detections.from_wire(candidate, strict=False)
    if max(ours.has_mask().sum(), theirs.has_mask().sum()) > MAX_MASKS:
        frame_size = None
    return frame_agreement(ours, theirs, MIN_IOU, frame_size)
