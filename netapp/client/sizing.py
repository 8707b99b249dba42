"""How big a frame goes on the wire, and how boxes found in it come back to the robot's own frame (pure).

A netapp advertises the size its processor consumes (`input_size`, width x height): a letterboxing detector fits
the frame inside that box, keeping its aspect ratio, so a frame already fitted inside it gives the model the same
pixels the full frame would have (the netapp's resize becomes a no-op). The robot sends no more than that, and no
more than its own `SendSettings.long_side` cap; never more than the source (`docs/client.md#what-is-sent`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from netapp.results import KEYPOINTS_FIELD, MASK_FIELD, POLYGONS_KEY, RBOX_FIELD, field_problem

Size = tuple[int, int]  # (width, height)


def fit_scale(source: Size, input_size: Size | None, long_side: int | None = None, full_frames: bool = False) -> float:
    """The scale (at most 1) that fits `source` inside the processor's `input_size` (skipped with `full_frames`)
    and within `long_side` on its long side."""
    width, height = source
    scale = 1.0
    if input_size is not None and not full_frames:
        scale = min(scale, input_size[0] / width, input_size[1] / height)  # the letterbox's own ratio
    if long_side is not None:
        scale = min(scale, long_side / max(width, height))
    return scale


def send_size(source: Size, input_size: Size | None, long_side: int | None = None, full_frames: bool = False) -> Size:
    """The (width, height) to send `source` at: itself when no downscaling is asked for, else scaled by
    `fit_scale` and rounded up to even sides (H.264's yuv420p needs them; never below 2, never above the source)."""
    scale = fit_scale(source, input_size, long_side, full_frames)
    if scale >= 1.0:
        return source
    return tuple(min(side, max(2, _even_up(side * scale))) for side in source)  # type: ignore[return-value]


def _even_up(value: float) -> int:
    whole = int(round(value))
    return whole + (whole % 2)


def to_source_coordinates(message: dict[str, Any], sent: Size, source: Size) -> dict[str, Any]:
    """A result message for a frame sent at `sent`, with its detections in `source` pixels (a copy; the message
    itself when nothing was scaled): each `bbox`, and the `mask` polygons, `keypoints` and `rbox` that are well formed
    (`netapp.results.field_problem`). An RLE mask stays at the size it was found at (`Result.masks` resizes it);
    anything else is left as the netapp sent it."""
    detections = message.get("detections")
    if sent == source or not isinstance(detections, list):
        return message
    sx, sy = source[0] / sent[0], source[1] / sent[1]
    scaled = [_scaled(d, sx, sy) for d in detections]
    return {**message, "detections": scaled}


def _scaled(detection: Any, sx: float, sy: float) -> Any:
    bbox = detection.get("bbox") if isinstance(detection, dict) else None
    if not (isinstance(bbox, list) and len(bbox) == 4 and all(isinstance(v, (int, float)) for v in bbox)):
        return detection
    x1, y1, x2, y2 = bbox
    out = {**detection, "bbox": [round(x1 * sx, 1), round(y1 * sy, 1), round(x2 * sx, 1), round(y2 * sy, 1)]}
    for name in (MASK_FIELD, KEYPOINTS_FIELD, RBOX_FIELD):
        if name in detection and field_problem(name, detection[name]) is None:
            out[name] = _scaled_field(name, detection[name], sx, sy)
    return out


def _scaled_field(name: str, value: Any, sx: float, sy: float) -> Any:
    """A well-formed mask, keypoints or rbox field scaled by (sx, sy) (the robot keeps the aspect ratio, so sx and
    sy differ only by rounding: an oriented box's sides take their mean)."""
    if name == MASK_FIELD:
        if POLYGONS_KEY not in value:
            return value
        return {POLYGONS_KEY: [_scaled_points(p, sx, sy) for p in value[POLYGONS_KEY]]}
    if name == KEYPOINTS_FIELD:
        return [[round(x * sx, 1), round(y * sy, 1), score] for x, y, score in value]
    cx, cy, w, h, angle = value
    s = (sx + sy) / 2
    return [round(cx * sx, 1), round(cy * sy, 1), round(w * s, 1), round(h * s, 1), angle]


def _scaled_points(flat: list[float], sx: float, sy: float) -> list[float]:
    if not flat:
        return flat
    points = np.asarray(flat, np.float64).reshape(-1, 2) * (sx, sy)
    return np.round(points, 1).ravel().tolist()
