"""JPEG frames: received bytes checked at once and turned into BGR images later, with errors a robot developer
can act on."""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from netapp.frame import EncodedFrame
from netapp.server.decoding.image_limits import check_pixels, jpeg_size
from netapp.server.errors import FrameRejected

JPEG_MAGIC = b"\xff\xd8\xff"


def check_jpeg(data: bytes) -> None:
    """The checks that need no decoding; ValueError saying what is wrong."""
    if not data:
        raise ValueError("empty frame: the body must hold one JPEG image")
    if not data.startswith(JPEG_MAGIC):
        raise ValueError(f"not a JPEG image (it starts with {data[:4].hex()}, a JPEG starts with ffd8ff)")


def jpeg_frame(data: bytes, max_pixels: int) -> Callable[[], np.ndarray]:
    """Check a received JPEG at once, its pixel count read from its header (FrameRejected: 400, or 413 over
    `max_pixels`), and return its decoding for the pipeline to run."""
    try:
        check_jpeg(data)
        width, height = jpeg_size(data)
    except ValueError as exc:
        raise FrameRejected("bad_frame", str(exc)) from exc
    check_pixels(width, height, max_pixels, "a JPEG")
    return lambda: decode_jpeg(data)


def decode_jpeg(data: bytes) -> np.ndarray:
    """One JPEG file -> BGR uint8 image; ValueError saying why not."""
    check_jpeg(data)
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if image is None or image.size == 0:
        raise ValueError(f"corrupt JPEG: could not decode {len(data)} bytes")
    return image


class JpegDecoder:
    """JPEG frames (Socket.IO's `image` event, the frames wire's JPEG codec, HTTP's body): every frame stands
    alone, so one instance serves every connection."""

    in_order = False  # any thread, any order

    def __init__(self, max_pixels: int) -> None:
        self.max_pixels = max_pixels

    def frame(self, frame: EncodedFrame) -> Callable[[], np.ndarray]:
        return jpeg_frame(frame.payload, self.max_pixels)

    def reset(self) -> None:
        pass

    def close(self) -> None:
        pass
