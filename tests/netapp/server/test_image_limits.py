"""Picture sizes read from headers, before any decoding: JPEG frame headers and H.264 sequence parameter sets."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from netapp.server.decoding.h264_bitstream import sps_sizes
from netapp.server.decoding.image_limits import MAX_JPEG_SEGMENTS, check_pixels, jpeg_size
from netapp.server.errors import FrameRejected
from tests.support.attacks import h264_keyframe_claiming, h264_sps, jpeg_claiming


def encode(width: int, height: int, *params: int) -> bytes:
    ok, buf = cv2.imencode(".jpg", np.full((height, width, 3), 90, np.uint8), list(params))
    assert ok
    return buf.tobytes()


@pytest.mark.parametrize("size", [(1, 1), (640, 480), (33, 2001)])
def test_jpeg_size_matches_what_opencv_decodes(size) -> None:
    data = encode(*size)
    assert jpeg_size(data) == size
    height, width = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR).shape[:2]
    assert (width, height) == size


def test_jpeg_size_of_a_progressive_jpeg_with_exif_like_segments() -> None:
    data = encode(320, 200, cv2.IMWRITE_JPEG_PROGRESSIVE, 1)
    app1 = b"\xff\xe1" + (2 + 5000).to_bytes(2, "big") + b"\xff\xc0" * 2500  # a SOF look-alike inside APP1
    assert jpeg_size(data[:2] + app1 + b"\xff\xff" + data[2:]) == (320, 200)  # fill byte before the next marker


def test_a_tiny_jpeg_claiming_a_huge_picture_is_read_as_huge() -> None:
    data = jpeg_claiming(65500, 16000)
    assert len(data) < 1000
    assert jpeg_size(data) == (65500, 16000)


@pytest.mark.parametrize(
    "data, message",
    [
        (b"\xff\xd8", "cut short"),
        (b"\xff\xd8\xff\xda\x00\x02", "image data before a frame header"),
        (b"\xff\xd8\xff\xe0\x00\x01", "segment length"),
        (b"\xff\xd8\xff\xc0\x00\x08\x08\x00", "cut short"),
        (b"\xff\xd8\xff\xc0\x00\x08\x08\x00\x00\x00\x10", "0"),
        (b"\xff\xd8" + b"\xff\xfe\x00\x02" * (MAX_JPEG_SEGMENTS + 1), "segments"),
        (b"\xff\xd8\x00\x00", "segment marker"),
        (b"GIF89a", "not a JPEG"),
    ],
)
def test_jpeg_size_refuses_what_has_no_usable_frame_header(data: bytes, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        jpeg_size(data)


def test_check_pixels_refuses_over_the_limit_with_413() -> None:
    check_pixels(3840, 2160, 3840 * 2160, "a JPEG")
    with pytest.raises(FrameRejected, match=r"65500x16000 .* limit of 100 pixels") as caught:
        check_pixels(65500, 16000, 100, "a JPEG")
    assert (caught.value.status, caught.value.reason) == (413, "too_many_pixels")


@pytest.mark.parametrize("size", [(64, 64), (16000, 16000), (1920, 1088)])
def test_sps_sizes_of_a_crafted_sps(size) -> None:
    assert sps_sizes(h264_sps(*size)) == [size]


def test_sps_sizes_of_a_real_stream_and_of_a_keyframe_claiming_more() -> None:
    pytest.importorskip("av")
    from netapp.client.h264 import H264Encoder

    encoder = H264Encoder(320, 180)
    packets, keyframe = encoder.encode(np.zeros((180, 320, 3), np.uint8))
    assert keyframe
    assert sps_sizes(packets) == [(320, 192)]  # whole macroblocks; the SPS crops the rest
    assert sps_sizes(h264_keyframe_claiming(packets, 16000, 16000)) == [(16000, 16000)]
    assert sps_sizes(encoder.encode(np.zeros((180, 320, 3), np.uint8))[0]) == []  # no SPS in a P-frame
    with pytest.raises(ValueError, match="cut short"):
        sps_sizes(b"\x00\x00\x01\x67\x42")
