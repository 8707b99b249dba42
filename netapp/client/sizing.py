"""How big a frame goes on the wire, and how boxes found in it come back to the robot's own frame (pure).

A netapp advertises the size its processor consumes (`input_size`, width x height): a letterboxing detector fits
the frame inside that box, keeping its aspect ratio, so a frame already fitted inside it gives the model the same
pixels the full frame would have (the netapp's resize becomes a no-op). The robot sends no more than that, and no
more than its own `SendSettings.long_side` cap; never more than the source (`docs/client.md#what-is-sent`).
"""

from __future__ import annotations

from typing import Any

from netapp.detections import Detections
from netapp.results import DETECTIONS_FIELD

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
    itself when nothing was scaled): `Detections.scaled` (boxes, mask polygons, keypoints, oriented boxes). An RLE
    mask stays at the size it was found at (`Result.masks` resizes it); what is malformed, and anything else, is left
    as the netapp sent it."""
    if sent == source or not isinstance(message.get(DETECTIONS_FIELD), list):
        return message
    detections = Detections.from_wire(message, strict=False)
    return detections.scaled(source[0] / sent[0], source[1] / sent[1]).to_wire()
