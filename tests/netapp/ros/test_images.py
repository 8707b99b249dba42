"""ROS image messages to frames (pure): channel order, 16-bit mono, row padding and byte order."""

from __future__ import annotations

import numpy as np
import pytest

from netapp.ros.images import compressed_format, raw_to_bgr
from tests.support.images import make_jpeg


def test_rgb8_becomes_bgr_and_row_padding_is_dropped():
    rgb = np.zeros((2, 3, 3), np.uint8)
    rgb[..., 0] = 200  # red
    padded = np.zeros((2, 12), np.uint8)  # step 12 for rows of 9 bytes
    padded[:, :9] = rgb.reshape(2, 9)
    bgr = raw_to_bgr("rgb8", 2, 3, 12, False, padded.ravel())
    assert bgr.shape == (2, 3, 3) and (bgr[..., 2] == 200).all() and (bgr[..., :2] == 0).all()


@pytest.mark.parametrize("bigendian", [False, True])
def test_mono16_is_scaled_by_its_top_byte_in_either_byte_order(bigendian):
    values = np.array([[0, 0x8000], [0xFF00, 0x0100]], np.uint16)
    data = values.astype(">u2" if bigendian else "<u2").view(np.uint8).ravel()
    bgr = raw_to_bgr("mono16", 2, 2, 4, bigendian, data)
    assert bgr[..., 0].tolist() == [[0, 0x80], [0xFF, 0x01]] and (bgr[..., 0] == bgr[..., 2]).all()


def test_a_16uc1_depth_image_spans_its_own_range():
    depth = np.array([[500, 1000], [1500, 2000]], "<u2")  # millimetres
    bgr = raw_to_bgr("16UC1", 2, 2, 4, False, depth.view(np.uint8).ravel())
    assert bgr[..., 0].tolist() == [[0, 85], [170, 255]]


def test_compressed_images_are_told_by_their_bytes_not_their_format_field():
    assert compressed_format(make_jpeg()) == "jpeg"
    assert compressed_format(b"\x89PNG\r\n\x1a\n" + b"\0" * 8) == "png"
