"""A netapp detection as the fields of a `vision_msgs/msg/Detection2D` (pure), for the MCAP output and the live
bridge alike: the class name as `class_id`, the score, the box as center and size in the image's pixels, the track id
as `id` (the tracking netapp)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from netapp.detections import Detections, as_detections


@dataclass(frozen=True)
class VisionDetection:
    class_id: str
    score: float
    center_x: float
    center_y: float
    size_x: float
    size_y: float
    id: str


def vision_detections(detections: Detections | list[Any]) -> list[VisionDetection]:
    """The boxes of a result's detections (`Detections`, or the wire list read leniently: anything else in it, a
    custom processor's output, is left out)."""
    dets = as_detections(detections)
    centers = (dets.xyxy[:, :2] + dets.xyxy[:, 2:]) / 2
    sizes = dets.xyxy[:, 2:] - dets.xyxy[:, :2]
    tracks = dets.tracker_id if dets.tracker_id is not None else np.full(len(dets), -1)
    return [
        VisionDetection(
            class_id=dets.class_text(i) if dets.class_name[i] is not None or dets.class_id[i] >= 0 else "",
            score=0.0 if np.isnan(dets.confidence[i]) else float(dets.confidence[i]),
            center_x=float(centers[i, 0]),
            center_y=float(centers[i, 1]),
            size_x=float(sizes[i, 0]),
            size_y=float(sizes[i, 1]),
            id="" if tracks[i] < 0 else str(int(tracks[i])),
        )
        for i in range(len(dets))
    ]
