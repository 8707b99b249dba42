"""How big a picture is, read from its header before any decoding, and the check against `--max-pixels`.

A 629-byte JPEG may claim 65500x16000 pixels and an H.264 SPS 16000x16000: decoding them first allocates gigabytes.
The header says the size for a few microseconds of work, so a frame over the limit is refused before it costs
anything (413 / data_error `too_many_pixels`).
"""

from __future__ import annotations

from netapp.server.errors import FrameRejected

# Start-of-frame markers (ITU T.81 B.1.1.3): baseline, extended, progressive, lossless, arithmetic-coded variants.
# 0xC4 (DHT), 0xC8 (JPG) and 0xCC (DAC) share the range but are not frame headers.
_SOF_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
_STANDALONE = frozenset({0x01, *range(0xD0, 0xD8)})  # TEM, RSTn: no length field
_SOS, _EOI = 0xDA, 0xD9
MAX_JPEG_SEGMENTS = 256  # real files put a dozen segments (APPn, DQT, DHT) before the frame header


def jpeg_size(data: bytes) -> tuple[int, int]:
    """(width, height) from a JPEG's frame header (SOFn), walking the segments before it; ValueError if the file
    has none there or is cut short. Never decodes, never reads more than the headers."""
    if not data.startswith(b"\xff\xd8"):
        raise ValueError("not a JPEG image (it does not start with ffd8)")
    pos, segments = 2, 0
    while True:
        segments += 1
        if segments > MAX_JPEG_SEGMENTS:
            raise ValueError(f"not a usable JPEG: over {MAX_JPEG_SEGMENTS} segments before the frame header")
        while pos + 1 < len(data) and data[pos] == data[pos + 1] == 0xFF:  # fill bytes before a marker
            pos += 1
        if pos + 1 >= len(data):
            raise ValueError("corrupt JPEG: cut short before its frame header (SOF)")
        if data[pos] != 0xFF:
            raise ValueError("corrupt JPEG: no frame header (SOF) where a segment marker should be")
        marker = data[pos + 1]
        pos += 2
        if marker in _STANDALONE:
            continue
        if marker in (_SOS, _EOI):
            raise ValueError("corrupt JPEG: image data before a frame header (SOF)")
        if pos + 2 > len(data):
            raise ValueError("corrupt JPEG: cut short in a segment header")
        length = int.from_bytes(data[pos : pos + 2], "big")
        if length < 2:
            raise ValueError("corrupt JPEG: a segment length below 2")
        if marker in _SOF_MARKERS:
            if length < 8 or pos + 7 > len(data):
                raise ValueError("corrupt JPEG: frame header (SOF) cut short")
            height = int.from_bytes(data[pos + 3 : pos + 5], "big")
            width = int.from_bytes(data[pos + 5 : pos + 7], "big")
            if width == 0 or height == 0:  # height 0 defers it to a DNL marker, which OpenCV cannot decode
                raise ValueError(f"unsupported JPEG: its frame header says {width}x{height} pixels")
            return width, height
        pos += length


def check_pixels(width: int, height: int, max_pixels: int, what: str) -> None:
    """FrameRejected (413) when width x height is over `max_pixels`."""
    if width * height > max_pixels:
        raise FrameRejected(
            "too_many_pixels",
            f"{what} of {width}x{height} = {width * height} pixels is over this netapp's limit of {max_pixels} "
            "pixels (--max-pixels): send smaller pictures",
            413,
        )
