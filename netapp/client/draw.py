"""Drawing a netapp's result on a BGR frame: boxes, class names, scores and the latency (pure, OpenCV only).

Robot code can call `draw_result` on its own frames; `netapp stream --save/--show` uses the same function.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

FONT = cv2.FONT_HERSHEY_SIMPLEX


def class_colour(class_id: int) -> tuple[int, int, int]:
    """A bright BGR colour per class, the same on every run (and on the netapp's page)."""
    hue = (class_id * 47) % 180  # a step coprime with 180 spreads neighbouring classes apart
    hsv = np.uint8([[[hue, 220, 255]]])
    b, g, r = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0]
    return int(b), int(g), int(r)


def label_of(detection: dict[str, Any]) -> str:
    name = detection.get("class_name", detection.get("class", "?"))
    score = detection.get("score")
    return f"{name} {score:.2f}" if isinstance(score, (int, float)) else str(name)


def draw_detections(
    frame: np.ndarray, detections: Sequence[dict[str, Any]], *, thickness: int = 2, copy: bool = True
) -> np.ndarray:
    """Boxes with `class_name score` labels; returns a new frame (or draws in place with `copy=False`).

    Detections are the netapp's `{"bbox": [x1, y1, x2, y2], "score", "class", "class_name"}` in the frame's pixels;
    anything else in the list (a custom processor's output) is skipped.
    """
    out = frame.copy() if copy else frame
    height, width = out.shape[:2]
    scale = max(0.4, min(width, height) / 800)
    boxed = [d for d in detections if isinstance(d, dict) and isinstance(d.get("bbox"), (list, tuple))]
    for detection in sorted(boxed, key=lambda d: d.get("score") or 0):  # the surest label drawn last, on top
        bbox = detection["bbox"]
        if len(bbox) != 4:
            continue
        x1, y1, x2, y2 = (int(round(float(v))) for v in bbox)
        colour = class_colour(int(detection.get("class", 0) or 0))
        cv2.rectangle(out, (x1, y1), (x2, y2), colour, thickness)
        text = label_of(detection)
        (tw, th), base = cv2.getTextSize(text, FONT, scale, 1)
        ty = y1 - 4 if y1 - th - base - 4 >= 0 else y1 + th + base + 4  # above the box, inside when at the top
        cv2.rectangle(out, (x1, ty - th - base), (x1 + tw + 4, ty + base // 2), colour, cv2.FILLED)
        cv2.putText(out, text, (x1 + 2, ty - base // 2), FONT, scale, (0, 0, 0), 1, cv2.LINE_AA)
    return out


def draw_caption(frame: np.ndarray, text: str, *, copy: bool = True) -> np.ndarray:
    """One line of text on a dark band at the top left (e.g. the latency)."""
    out = frame.copy() if copy else frame
    scale = max(0.4, min(out.shape[:2]) / 800)
    (tw, th), base = cv2.getTextSize(text, FONT, scale, 1)
    cv2.rectangle(out, (0, 0), (tw + 8, th + base + 8), (0, 0, 0), cv2.FILLED)
    cv2.putText(out, text, (4, th + 4), FONT, scale, (255, 255, 255), 1, cv2.LINE_AA)
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
    """A `netapp.client.Result` drawn on its frame: the boxes and the latency caption."""
    out = draw_detections(frame, result.detections, copy=copy)
    return draw_caption(out, latency_caption(result.latency_ms, getattr(result, "breakdown", None)), copy=False)
