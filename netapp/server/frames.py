"""Turning received bytes into BGR images, with errors a robot developer can act on."""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import Any, Protocol

import cv2
import numpy as np

from netapp.server.errors import FrameRejected
from netapp.server.image_limits import check_pixels, jpeg_size

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


class FrameDecoder(Protocol):
    """How one connection's frames of one event become images. Stateful for video (H.264 references earlier
    pictures), so each connection gets its own, and its transport resets it (RESET_STATE) and closes it."""

    def frame(self, message: dict[str, Any]) -> Callable[[], np.ndarray] | Awaitable[np.ndarray]:
        """A validated frame message -> the decoding for the pipeline to run, or (video, decoded in order on
        the stream's own runner) the picture to await; FrameRejected if it cannot be."""
        ...

    def reset(self) -> None: ...

    def close(self) -> None: ...


class JpegDecoder:
    """JPEG frames (the `image` event): every frame stands alone, so one instance serves every connection."""

    def __init__(self, max_pixels: int) -> None:
        self.max_pixels = max_pixels

    def frame(self, message: dict[str, Any]) -> Callable[[], np.ndarray]:
        return jpeg_frame(message["frame"], self.max_pixels)

    def reset(self) -> None:
        pass

    def close(self) -> None:
        pass
