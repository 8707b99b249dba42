"""One frame's two answers compared: the current model's result and the candidate's, as the robot would get them.
Pure; the matching itself (boxes, mask IoU, OKS) is `netapp.models.matching`'s."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from netapp.models.matching import FrameAgreement, frame_agreement
from netapp.results import CLASSIFICATIONS_FIELD, DETECTIONS_FIELD, MASK_FIELD, mask_to_array

MIN_IOU = 0.5  # a candidate box matches a current box of the same class that it overlaps by this much
MAX_MASKS = 100  # masks rasterised per frame to compare (each is a frame-sized array); past it boxes alone count


def _with_mask_arrays(detections: Sequence[Mapping[str, Any]], size: tuple[int, int] | None) -> list[Mapping[str, Any]]:
    """Detections whose wire masks (polygons or RLE) are boolean arrays of the frame, as `frame_agreement` wants
    them; without the frame's (width, height), or past MAX_MASKS, masks are left out of the comparison."""
    if size is None or sum(MASK_FIELD in d for d in detections) > MAX_MASKS:
        return list(detections)
    width, height = size
    out: list[Mapping[str, Any]] = []
    for d in detections:
        mask = d.get(MASK_FIELD)
        if isinstance(mask, Mapping):
            try:
                d = {**d, MASK_FIELD: mask_to_array(dict(mask), height, width)}
            except ValueError:
                pass  # a malformed mask is compared as a box
        out.append(d)
    return out


def compare_results(
    current: Mapping[str, Any], candidate: Mapping[str, Any], frame_size: tuple[int, int] | None = None
) -> FrameAgreement:
    """How well `candidate`'s result agrees with `current`'s for one frame: a classifier's top-1 (1 of 1 when the
    same class), else the detections matched by class and IoU >= MIN_IOU, with mask IoU and OKS of the matched
    pairs. `frame_size` (width, height) lets masks be compared."""
    current_top = current.get(CLASSIFICATIONS_FIELD) or []
    candidate_top = candidate.get(CLASSIFICATIONS_FIELD) or []
    if current_top or candidate_top:
        same = bool(current_top and candidate_top and current_top[0].get("class") == candidate_top[0].get("class"))
        return FrameAgreement(int(same), int(bool(candidate_top)), int(bool(current_top)))
    return frame_agreement(
        _with_mask_arrays(current.get(DETECTIONS_FIELD) or [], frame_size),
        _with_mask_arrays(candidate.get(DETECTIONS_FIELD) or [], frame_size),
        MIN_IOU,
    )
