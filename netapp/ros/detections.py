"""A netapp detection as the fields of a `vision_msgs/msg/Detection2D` (pure), for the MCAP output and the live
bridge alike: the class name as `class_id`, the score, the box as center and size in the image's pixels, the track id
as `id` (the tracking netapp)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class VisionDetection:
    class_id: str
    score: float
    center_x: float
    center_y: float
    size_x: float
    size_y: float
    id: str


def vision_detections(detections: list[Any]) -> list[VisionDetection]:
    """The boxes of a result's detections; anything else in the list (a custom processor's output) is left out."""
    out = []
    for d in detections:
        if not isinstance(d, dict) or "bbox" not in d:
            continue
        x1, y1, x2, y2 = (float(v) for v in d["bbox"])
        out.append(
            VisionDetection(
                class_id=str(d.get("class_name", d.get("class", ""))),
                score=float(d.get("score", 0.0)),
                center_x=(x1 + x2) / 2,
                center_y=(y1 + y2) / 2,
                size_x=x2 - x1,
                size_y=y2 - y1,
                id="" if d.get("track_id") is None else str(d["track_id"]),
            )
        )
    return out
