"""Letterboxing: resize keeping the aspect ratio, pad to the model's input size."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class Letterbox:
    """How an image was placed in the model input, to map boxes back to the original pixels."""

    ratio: float
    pad_x: float
    pad_y: float
    width: int  # original image size
    height: int


def letterbox(
    image: np.ndarray, size: tuple[int, int], *, center: bool, rgb: bool, scale: float, pad_value: float = 114.0
) -> tuple[np.ndarray, Letterbox]:
    """BGR uint8 HxWx3 -> float32 1x3xHxW blob and the placement.

    YOLOX pads at the bottom-right, takes BGR 0-255; Ultralytics exports centre the image and take RGB 0-1.
    """
    in_h, in_w = size
    h, w = image.shape[:2]
    ratio = min(in_h / h, in_w / w)
    new_w, new_h = max(1, round(w * ratio)), max(1, round(h * ratio))
    resized = cv2.resize(image, (new_w, new_h), interpolation=cv2.INTER_LINEAR) if (new_w, new_h) != (w, h) else image
    pad_x = (in_w - new_w) / 2 if center else 0.0
    pad_y = (in_h - new_h) / 2 if center else 0.0
    x0, y0 = int(round(pad_x - 0.1)), int(round(pad_y - 0.1))
    # One plane at a time (OpenCV splits HWC into planes): each is copied into the blob row by row, and only the
    # border is filled, a quarter less time than one strided HWC -> CHW copy into a filled blob.
    blob = np.empty((1, 3, in_h, in_w), dtype=np.float32)
    planes = cv2.split(resized)
    pad = pad_value * scale
    for channel, plane in enumerate(reversed(planes) if rgb else planes):
        out = blob[0, channel]
        out[:y0], out[y0 + new_h :] = pad, pad
        out[y0 : y0 + new_h, :x0], out[y0 : y0 + new_h, x0 + new_w :] = pad, pad
        inside = out[y0 : y0 + new_h, x0 : x0 + new_w]
        if scale != 1.0:
            cv2.multiply(plane, scale, dst=inside, dtype=cv2.CV_32F)
        else:
            inside[...] = plane
    return blob, Letterbox(ratio=ratio, pad_x=float(x0), pad_y=float(y0), width=w, height=h)


def unletterbox(boxes_xyxy: np.ndarray, lb: Letterbox) -> np.ndarray:
    """Boxes in model-input pixels -> boxes in original-image pixels, clipped to the image."""
    out = boxes_xyxy.astype(np.float32, copy=True)
    out[:, [0, 2]] = (out[:, [0, 2]] - lb.pad_x) / lb.ratio
    out[:, [1, 3]] = (out[:, [1, 3]] - lb.pad_y) / lb.ratio
    np.clip(out[:, [0, 2]], 0, lb.width, out=out[:, [0, 2]])
    np.clip(out[:, [1, 3]], 0, lb.height, out=out[:, [1, 3]])
    return out
