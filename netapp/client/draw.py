"""Drawing a netapp's result on a BGR frame: masks (a translucent fill in the class colour and its outline), boxes
with class names and scores, oriented boxes, keypoints and the skeleton's limbs, an image classification's top
classes and the latency (pure, OpenCV only). It reads a `netapp.detections.Detections`, whose `from_wire` checked
every field once: what is malformed is left out of it, so it is skipped here, never raised on.

Robot code can call `draw_result` on its own frames; `netapp stream --save/--show` uses the same function.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

from netapp.detections import Detections, as_detections, label_text
from netapp.results import CLASSIFICATIONS_FIELD, MASK_ALPHA, POLYGONS_KEY

FONT = cv2.FONT_HERSHEY_SIMPLEX
CAPTION_CLASSES = 3  # an image classification's top classes in the caption
PIXEL_LIMIT = 1 << 20  # coordinates are clipped to +-this before drawing (OpenCV's own limit is near 2**31 >> shift)


def class_colour(class_id: int) -> tuple[int, int, int]:
    """A bright BGR colour per class, the same on every run (and on the netapp's page)."""
    hue = (class_id * 47) % 180  # a step coprime with 180 spreads neighbouring classes apart
    hsv = np.uint8([[[hue, 220, 255]]])
    b, g, r = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0]
    return int(b), int(g), int(r)


def label_of(item: dict[str, Any]) -> str:
    """`name 0.91` of a classification's (or one wire detection's) dict."""
    score = item.get("score")
    return label_text(
        item.get("class_name", item.get("class", "?")), score if isinstance(score, (int, float)) else None
    )


def draw_detections(
    frame: np.ndarray, detections: Detections | Sequence[Any], *, thickness: int = 2, copy: bool = True
) -> np.ndarray:
    """Masks, boxes with `class_name score` labels, oriented boxes and keypoints; returns a new frame (or draws in
    place with `copy=False`).

    `detections` is a `Detections` or the netapp's wire list (read leniently: what is not a detection, a custom
    processor's output, and malformed fields are left out), in the frame's pixels.
    """
    out = frame.copy() if copy else frame
    dets = as_detections(detections)
    height, width = out.shape[:2]
    scale = max(0.4, min(width, height) / 800)
    dets = dets[np.argsort(np.nan_to_num(dets.confidence, nan=0.0), kind="stable")]  # the surest drawn on top
    draw_masks(out, dets)
    boxes = pixels(dets.xyxy)
    corners = pixels(np.nan_to_num(dets.rbox_corners(), nan=0.0))
    oriented, posed = dets.has_rbox(), dets.has_keypoints()
    for i in range(len(dets)):
        x1, y1, x2, y2 = boxes[i].tolist()
        colour = colour_of(dets, i)
        if oriented[i]:  # the oriented box is the outline; its axis-aligned box is thin
            cv2.polylines(out, [corners[i]], True, colour, thickness, cv2.LINE_AA)
        cv2.rectangle(out, (x1, y1), (x2, y2), colour, 1 if oriented[i] else thickness)
        if posed[i]:
            draw_keypoints(out, *dets.pose(i), colour, thickness)
        text = dets.label(i)
        (tw, th), base = cv2.getTextSize(text, FONT, scale, 1)
        ty = y1 - 4 if y1 - th - base - 4 >= 0 else y1 + th + base + 4  # above the box, inside when at the top
        cv2.rectangle(out, (x1, ty - th - base), (x1 + tw + 4, ty + base // 2), colour, cv2.FILLED)
        cv2.putText(out, text, (x1 + 2, ty - base // 2), FONT, scale, (0, 0, 0), 1, cv2.LINE_AA)
    return out


def pixels(values: Any) -> np.ndarray:
    """Finite coordinates (checked by `Detections.from_wire`) as int32 pixels OpenCV can draw, clipped far outside
    any frame (one of 1e300 would make OpenCV raise)."""
    array = np.asarray(values, np.float64)
    return np.round(np.clip(array, -PIXEL_LIMIT, PIXEL_LIMIT)).astype(np.int32)


def colour_of(detections: Detections, i: int) -> tuple[int, int, int]:
    return class_colour(max(0, int(detections.class_id[i])))


def draw_masks(out: np.ndarray, detections: Detections) -> None:
    """Each detection's mask, in place: one translucent blend for all the fills (the surest mask on top where
    they overlap), then the outlines. Polygons are filled as they are; an RLE is decoded at the frame's size and
    traced within its rows and columns."""
    height, width = out.shape[:2]
    overlay: np.ndarray | None = None
    outlines: list[tuple[list[np.ndarray], tuple[int, int, int]]] = []
    for i, mask in enumerate(detections.masks):
        if mask is None:
            continue
        colour = colour_of(detections, i)
        if overlay is None:
            overlay = out.copy()
        if isinstance(mask, dict) and POLYGONS_KEY in mask:
            points = _polygon_pixels(mask[POLYGONS_KEY])
            cv2.fillPoly(overlay, points, colour)
            outlines.append((points, colour))
            continue
        window = _mask_window(detections.mask_array(i, height, width))
        if window is None:
            continue
        inside, x1, y1 = window
        # Its outline, holes included (two levels), filled even-odd like polygons: far cheaper than a boolean
        # assignment into the colour image.
        contours, _ = cv2.findContours(inside, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE, offset=(x1, y1))
        cv2.fillPoly(overlay, list(contours), colour)
        outlines.append((list(contours), colour))
    if overlay is None:
        return
    cv2.addWeighted(overlay, MASK_ALPHA, out, 1 - MASK_ALPHA, 0, dst=out)  # unmasked pixels blend to themselves
    for points, colour in outlines:  # 1-pixel outlines: anti-aliasing them cost 5x (a ragged mask has thousands)
        cv2.polylines(out, points, True, colour, 1, cv2.LINE_8)


def _polygon_pixels(polygons: list[list[float]]) -> list[np.ndarray]:
    """A checked mask's flat polygons as OpenCV's point arrays (those of 3 points or more), converted in one call."""
    lengths = [len(p) // 2 for p in polygons]
    flat = pixels([v for p in polygons for v in p])
    if not flat.size:
        return []
    points = np.split(flat.reshape(-1, 2), np.cumsum(lengths)[:-1])
    return [p for p in points if len(p) >= 3]


def _mask_window(array: np.ndarray | None) -> tuple[np.ndarray, int, int] | None:
    """A frame-sized mask's pixels in the smallest window that holds them, as uint8 (0 or 1), with the window's top
    left; None for an empty one."""
    if array is None:
        return None
    # An RLE decodes column by column (array.T is contiguous): its columns first, then its rows among them, and
    # only that window copied row-major; a whole-frame copy per mask would cost ten times as much.
    columns = array.T
    cols = np.flatnonzero(columns.any(axis=1))
    if not cols.size:
        return None
    x1, x2 = int(cols[0]), int(cols[-1]) + 1
    rows = np.flatnonzero(columns[x1:x2].any(axis=0))
    y1, y2 = int(rows[0]), int(rows[-1]) + 1
    return np.ascontiguousarray(columns[x1:x2, y1:y2].T).view(np.uint8), x1, y1


def draw_keypoints(
    out: np.ndarray,
    points: list[tuple[float, float]],
    limbs: list[tuple[tuple[float, float], tuple[float, float]]],
    colour: tuple[int, int, int],
    thickness: int = 2,
) -> None:
    """A pose in place (`Detections.pose`: the sure keypoints and the limbs between them): the limbs in the class
    colour, then each keypoint as a dot."""
    for (ax, ay), (bx, by) in pixels(limbs).reshape(-1, 2, 2).tolist():
        cv2.line(out, (ax, ay), (bx, by), colour, thickness, cv2.LINE_AA)
    radius = max(2, thickness + 1)
    for x, y in pixels(points).reshape(-1, 2).tolist():
        cv2.circle(out, (x, y), radius, (255, 255, 255), cv2.FILLED, cv2.LINE_AA)
        cv2.circle(out, (x, y), radius, colour, 1, cv2.LINE_AA)


def classification_caption(classifications: Any, top: int = CAPTION_CLASSES) -> str | None:
    """`golden retriever 0.60, labrador 0.30, ...`: an image classification's first `top` classes; None for none."""
    if not isinstance(classifications, list):
        return None
    items = [c for c in classifications[:top] if isinstance(c, dict)]
    return ", ".join(label_of(c) for c in items) or None


def draw_caption(frame: np.ndarray, text: str, *, copy: bool = True, line: int = 0) -> np.ndarray:
    """One line of text on a dark band at the top left (e.g. the latency); `line` 1, 2, ... goes below it."""
    out = frame.copy() if copy else frame
    scale = max(0.4, min(out.shape[:2]) / 800)
    (tw, th), base = cv2.getTextSize(text, FONT, scale, 1)
    top = line * (th + base + 8)
    cv2.rectangle(out, (0, top), (tw + 8, top + th + base + 8), (0, 0, 0), cv2.FILLED)
    cv2.putText(out, text, (4, top + th + 4), FONT, scale, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def latency_caption(latency_ms: float | None, breakdown: Any = None) -> str:
    """`latency 42 ms (up 3 / queue 1 / infer 30 / down 8)`; `breakdown` is a LatencyBreakdown or None."""
    if latency_ms is None:
        return "no result yet"
    text = f"latency {latency_ms:.0f} ms"
    if breakdown is not None:
        text += (
            f" (up {breakdown.uplink_ms:.0f} / queue {breakdown.queue_ms:.0f} / infer {breakdown.inference_ms:.0f}"
            f" / down {breakdown.downlink_ms:.0f})"
        )
    return text


def draw_result(frame: np.ndarray, result: Any, *, copy: bool = True) -> np.ndarray:
    """A `netapp.client.Result` drawn on its frame: its detections (`draw_detections`), the latency caption and,
    below it, an image classification's top classes."""
    out = draw_detections(frame, result.detections, copy=copy)
    out = draw_caption(out, latency_caption(result.latency_ms, getattr(result, "breakdown", None)), copy=False)
    message = getattr(result, "message", None)
    classes = classification_caption(message.get(CLASSIFICATIONS_FIELD) if isinstance(message, dict) else None)
    return draw_caption(out, classes, copy=False, line=1) if classes else out
