"""Test images made here (no media needed)."""

from __future__ import annotations

import cv2
import numpy as np


def make_jpeg(width: int = 128, height: int = 96, colour: tuple[int, int, int] = (40, 120, 200)) -> bytes:
    """A JPEG of a coloured field with a white square in its upper-left quarter."""
    image = np.zeros((height, width, 3), np.uint8)
    image[:] = colour
    cv2.rectangle(image, (width // 4, height // 4), (width // 2, height // 2), (255, 255, 255), -1)
    ok, buf = cv2.imencode(".jpg", image)
    assert ok
    return buf.tobytes()
