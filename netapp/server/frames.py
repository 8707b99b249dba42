"""Turning received bytes into BGR images, with errors a robot developer can act on."""

from __future__ import annotations

import cv2
import numpy as np

JPEG_MAGIC = b"\xff\xd8\xff"


def decode_jpeg(data: bytes) -> np.ndarray:
    """One JPEG file -> BGR uint8 image; ValueError saying why not."""
    if not data:
        raise ValueError("empty frame: the body must hold one JPEG image")
    if not data.startswith(JPEG_MAGIC):
        raise ValueError(f"not a JPEG image (it starts with {data[:4].hex()}, a JPEG starts with ffd8ff)")
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if image is None or image.size == 0:
        raise ValueError(f"corrupt JPEG: could not decode {len(data)} bytes")
    return image
