"""Hostile inputs, built small: shared by tests/netapp/server/test_hostile.py and bench/hostile.py."""

from __future__ import annotations

import cv2
import numpy as np


def jpeg_claiming(width: int, height: int) -> bytes:
    """A tiny real JPEG (a few hundred bytes) whose frame header claims width x height pixels."""
    ok, buf = cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))
    assert ok
    data = bytearray(buf.tobytes())
    sof = data.find(b"\xff\xc0")
    data[sof + 5 : sof + 7] = height.to_bytes(2, "big")
    data[sof + 7 : sof + 9] = width.to_bytes(2, "big")
    return bytes(data)


class _BitWriter:
    def __init__(self) -> None:
        self.bits: list[int] = []

    def u(self, n: int, value: int) -> None:
        self.bits += [(value >> (n - 1 - i)) & 1 for i in range(n)]

    def ue(self, value: int) -> None:
        code = value + 1
        self.u(2 * code.bit_length() - 1, code)

    def rbsp(self) -> bytes:
        bits = self.bits + [1]  # rbsp_stop_one_bit
        bits += [0] * (-len(bits) % 8)
        raw = bytes(int("".join(map(str, bits[i : i + 8])), 2) for i in range(0, len(bits), 8))
        out = bytearray()
        zeros = 0
        for byte in raw:  # emulation prevention, as an encoder writes it
            if zeros >= 2 and byte <= 3:
                out.append(3)
                zeros = 0
            out.append(byte)
            zeros = zeros + 1 if byte == 0 else 0
        return bytes(out)


def h264_sps(width: int, height: int) -> bytes:
    """An Annex B baseline-profile SPS NAL unit that announces width x height (multiples of 16)."""
    b = _BitWriter()
    b.u(8, 66)  # profile_idc: baseline
    b.u(8, 0)  # constraint flags
    b.u(8, 52)  # level_idc 5.2
    b.ue(0)  # seq_parameter_set_id
    b.ue(0)  # log2_max_frame_num_minus4
    b.ue(2)  # pic_order_cnt_type
    b.ue(1)  # max_num_ref_frames
    b.u(1, 0)  # gaps_in_frame_num_value_allowed_flag
    b.ue(width // 16 - 1)
    b.ue(height // 16 - 1)
    b.u(1, 1)  # frame_mbs_only_flag
    b.u(1, 1)  # direct_8x8_inference_flag
    b.u(1, 0)  # frame_cropping_flag
    b.u(1, 0)  # vui_parameters_present_flag
    return b"\x00\x00\x00\x01\x67" + b.rbsp()


def h264_keyframe_claiming(packets: bytes, width: int, height: int) -> bytes:
    """A real keyframe's packets with its SPS replaced by one that announces width x height."""
    start = packets.find(b"\x00\x00\x01\x67")
    end = packets.find(b"\x00\x00\x01", start + 4)
    if start < 0 or end < 0:
        raise ValueError("no SPS in these packets")
    if start > 0 and packets[start - 1] == 0:
        start -= 1
    return packets[:start] + h264_sps(width, height) + packets[end - (1 if packets[end - 1] == 0 else 0) :]


def corrupt_jpeg() -> bytes:
    """A JPEG whose headers are fine (8x8 pixels) but whose image data cannot be decoded."""
    ok, buf = cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))
    assert ok
    data = buf.tobytes()
    sof = data.find(b"\xff\xc0")
    return b"\xff\xd8" + data[sof : sof + 2 + int.from_bytes(data[sof + 2 : sof + 4], "big")] + b"\x00" * 200
