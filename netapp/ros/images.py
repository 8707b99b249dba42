"""ROS image messages -> frames (pure): `sensor_msgs/msg/Image` in the common encodings to a BGR array, a
`CompressedImage` kept as its JPEG or PNG bytes. A message that cannot be a frame raises `ImageRefused`."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from netapp.client.frames import SourceFrame

MAX_PIXELS = 40_000_000  # an image claiming more (a corrupt header, a hostile bag) is refused before any copy

# encoding -> (channels, numpy dtype, conversion to BGR or None)
ENCODINGS: dict[str, tuple[int, str, int | None]] = {
    "rgb8": (3, "u1", cv2.COLOR_RGB2BGR),
    "bgr8": (3, "u1", None),
    "8UC3": (3, "u1", None),
    "rgba8": (4, "u1", cv2.COLOR_RGBA2BGR),
    "bgra8": (4, "u1", cv2.COLOR_BGRA2BGR),
    "mono8": (1, "u1", cv2.COLOR_GRAY2BGR),
    "8UC1": (1, "u1", cv2.COLOR_GRAY2BGR),
    "mono16": (1, "u2", cv2.COLOR_GRAY2BGR),
    "16UC1": (1, "u2", cv2.COLOR_GRAY2BGR),
}


class ImageRefused(ValueError):
    """A message that is no usable frame; the reason is one line (it names the encoding or the fault)."""


def compressed_format(data: bytes) -> str:
    """ "jpeg" or "png" by the bytes' magic number (the `format` field is free text: "rgb8; jpeg compressed bgr8")."""
    if data[:3] == b"\xff\xd8\xff":
        return "jpeg"
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        return "png"
    raise ImageRefused("a CompressedImage that is neither JPEG nor PNG")


def raw_to_bgr(encoding: str, height: int, width: int, step: int, bigendian: bool, data: Any) -> np.ndarray:
    """An `Image`'s pixels as a BGR uint8 array; 16-bit mono is scaled to 8 bits (mono16 by its top byte, a
    16UC1 depth image by its own range)."""
    if encoding not in ENCODINGS:
        raise ImageRefused(f"image encoding {encoding!r} is not supported (supported: {', '.join(ENCODINGS)})")
    channels, kind, conversion = ENCODINGS[encoding]
    dtype = np.dtype(kind).newbyteorder(">" if bigendian else "<")
    row = width * channels * dtype.itemsize
    if not (0 < width and 0 < height and width * height <= MAX_PIXELS):
        raise ImageRefused(f"an image of {width}x{height} pixels (at most {MAX_PIXELS} are taken)")
    if step < row or len(data) < step * height:
        raise ImageRefused(f"an image whose data ({len(data)} bytes) is shorter than {height} rows of {step} bytes")
    raw = (
        np.frombuffer(data, np.uint8)
        if isinstance(data, (bytes, bytearray, memoryview))
        else np.asarray(data, np.uint8)
    )
    rows = raw[: step * height].reshape(height, step)[:, :row]
    pixels = np.ascontiguousarray(rows).view(dtype).reshape(height, width, channels)
    if dtype.itemsize == 2:
        pixels = pixels.astype(np.uint16)
        if encoding == "mono16":
            pixels = (pixels >> 8).astype(np.uint8)
        else:
            pixels = cv2.normalize(pixels, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    pixels = pixels.reshape(height, width) if channels == 1 else pixels
    return cv2.cvtColor(pixels, conversion) if conversion is not None else np.ascontiguousarray(pixels)


def to_frame(msgtype: str, message: Any, stamp_offset_s: float | None) -> SourceFrame:
    """An image message as a `SourceFrame` stamped with its header stamp."""
    stamp_ns = message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec
    frame = SourceFrame(stamp_ns, offset_s=stamp_offset_s, frame_id=message.header.frame_id)
    if msgtype.endswith("CompressedImage"):
        frame.encoded = bytes(message.data)
        frame.format = compressed_format(frame.encoded)
        if frame.format == "png":  # sent decoded: decode it now, so a corrupt one is skipped here
            try:
                frame.bgr()
            except ValueError as exc:
                raise ImageRefused(str(exc)) from None
    else:
        frame.image = raw_to_bgr(
            message.encoding, message.height, message.width, message.step, bool(message.is_bigendian), message.data
        )
    return frame
