"""Just enough H.264 bitstream reading (Annex B) to tell where a stream can start and when a picture is missing.

FFmpeg conceals a lost reference picture instead of failing: the frames after it decode "fine" into wrong
pictures until the next keyframe. A robot whose library drops encoded packets under back-pressure (era-5g-client
does) would get detections on damaged pictures. The slice header's `frame_num` grows by one per reference picture
(H.264 7.4.3), so a jump shows that one went missing; the decoder then resets and waits for the next keyframe.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass

NAL_SLICE, NAL_IDR, NAL_SPS, NAL_PPS = 1, 5, 7, 8
HEADER_BYTES = 1024  # parameter sets and slice headers are far shorter; slice data is never read
_HIGH_PROFILES = {100, 110, 122, 244, 44, 83, 86, 118, 128, 138, 139, 134, 135}  # SPS with chroma/bit-depth fields
_EMULATION_PREVENTION = re.compile(b"\x00\x00\x03")
_SPS_START = re.compile(b"\x00\x00\x01[\x07\x27\x47\x67]")  # a start code, then an SPS NAL header (any nal_ref_idc)
MAX_SPS_PER_PACKET = 32  # an encoder writes one per keyframe


def nal_units(data: bytes) -> Iterator[bytes]:
    """The NAL units of an Annex B byte stream, each cut to its first HEADER_BYTES."""
    starts = []
    i = data.find(b"\x00\x00\x01")
    while i >= 0:
        starts.append(i + 3)
        i = data.find(b"\x00\x00\x01", i + 3)
    for k, start in enumerate(starts):
        end = starts[k + 1] - 3 if k + 1 < len(starts) else len(data)
        if start < end:
            yield data[start : min(end, start + HEADER_BYTES)]


def contains_idr(data: bytes) -> bool:
    """Whether the packets hold an IDR slice, where decoding can start (x264 puts SPS/PPS in front of it)."""
    return any(nal[0] & 0x1F == NAL_IDR for nal in nal_units(data))


class _Bits:
    """An RBSP bit reader (IndexError past the end)."""

    def __init__(self, nal_payload: bytes) -> None:
        self.data = _EMULATION_PREVENTION.sub(b"\x00\x00", nal_payload)
        self.pos = 0

    def u(self, n: int) -> int:
        value = 0
        for _ in range(n):
            value = (value << 1) | ((self.data[self.pos >> 3] >> (7 - (self.pos & 7))) & 1)
            self.pos += 1
        return value

    def ue(self) -> int:
        zeros = 0
        while self.u(1) == 0:
            zeros += 1
            if zeros > 31:
                raise ValueError("invalid exp-Golomb code")
        return (1 << zeros) - 1 + self.u(zeros)

    def se(self) -> int:
        k = self.ue()
        return (k + 1) // 2 if k & 1 else -(k // 2)


@dataclass(frozen=True)
class SequenceInfo:
    log2_max_frame_num: int
    separate_colour_planes: bool
    gaps_allowed: bool
    width: int = 0  # coded size in pixels (whole macroblocks): what the decoder allocates per picture
    height: int = 0


def parse_sps(payload: bytes) -> tuple[int, SequenceInfo]:
    """(seq_parameter_set_id, what slice headers need) from an SPS payload (after the NAL header byte)."""
    b = _Bits(payload)
    profile = b.u(8)
    b.u(16)  # constraint flags, level
    sps_id = b.ue()
    separate = False
    if profile in _HIGH_PROFILES:
        chroma_format = b.ue()
        if chroma_format == 3:
            separate = bool(b.u(1))
        b.ue()  # bit_depth_luma_minus8
        b.ue()  # bit_depth_chroma_minus8
        b.u(1)  # qpprime_y_zero_transform_bypass
        if b.u(1):  # seq_scaling_matrix_present
            for i in range(12 if chroma_format == 3 else 8):
                if b.u(1):
                    _skip_scaling_list(b, 16 if i < 6 else 64)
    log2_max_frame_num = b.ue() + 4
    poc_type = b.ue()
    if poc_type == 0:
        b.ue()
    elif poc_type == 1:
        b.u(1)  # delta_pic_order_always_zero
        b.se()  # offset_for_non_ref_pic
        b.se()  # offset_for_top_to_bottom_field
        for _ in range(b.ue()):
            b.se()
    b.ue()  # max_num_ref_frames
    gaps_allowed = bool(b.u(1))
    width_mbs = b.ue() + 1
    height_map_units = b.ue() + 1
    frame_mbs_only = b.u(1)
    height_mbs = height_map_units * (2 - frame_mbs_only)  # interlaced: map units are field macroblock pairs
    return sps_id, SequenceInfo(log2_max_frame_num, separate, gaps_allowed, width_mbs * 16, height_mbs * 16)


def sps_sizes(data: bytes) -> list[tuple[int, int]]:
    """(width, height) of every SPS in these packets (coded size, whole macroblocks); ValueError for an SPS
    that cannot be read, or for more than MAX_SPS_PER_PACKET of them. Cheap: a regex finds them (C speed, even
    in 8 MB of slice data) and only their first bytes are parsed."""
    sizes = []
    for match in _SPS_START.finditer(data):
        if len(sizes) == MAX_SPS_PER_PACKET:
            raise ValueError(f"H.264: over {MAX_SPS_PER_PACKET} sequence parameter sets (SPS) in one frame")
        try:
            _, info = parse_sps(data[match.end() : match.end() + HEADER_BYTES])
        except IndexError:
            raise ValueError("H.264: a sequence parameter set (SPS) is cut short") from None
        sizes.append((info.width, info.height))
    return sizes


def _skip_scaling_list(b: _Bits, size: int) -> None:
    last = next_scale = 8
    for _ in range(size):
        if next_scale:
            next_scale = (last + b.se() + 256) % 256
        last = next_scale or last


class FrameNumTracker:
    """Follows SPS/PPS and slice-header frame_num across one stream's packets."""

    def __init__(self) -> None:
        self._sps: dict[int, SequenceInfo] = {}
        self._pps: dict[int, int] = {}  # pps id -> sps id
        self._prev_ref: int | None = None  # frame_num of the last reference picture

    def reset(self) -> None:
        self._prev_ref = None

    def follows(self, data: bytes) -> bool:
        """False when a reference picture is missing before this packet's picture; True if fine or unknowable."""
        try:
            return self._follows(data)
        except (IndexError, ValueError):  # unparsable headers: FFmpeg will judge the data itself
            return True

    def _follows(self, data: bytes) -> bool:
        for nal in nal_units(data):
            nal_type, ref_idc = nal[0] & 0x1F, (nal[0] >> 5) & 3
            if nal_type == NAL_SPS:
                sps_id, info = parse_sps(nal[1:])
                self._sps[sps_id] = info
            elif nal_type == NAL_PPS:
                b = _Bits(nal[1:])
                pps_id = b.ue()
                self._pps[pps_id] = b.ue()
            elif nal_type in (NAL_SLICE, NAL_IDR):
                b = _Bits(nal[1:])
                b.ue()  # first_mb_in_slice
                b.ue()  # slice_type
                info = self._sps.get(self._pps.get(b.ue(), -1))
                if info is None:
                    return True
                if info.separate_colour_planes:
                    b.u(2)
                frame_num = b.u(info.log2_max_frame_num)
                follows = (
                    nal_type == NAL_IDR
                    or info.gaps_allowed
                    or self._prev_ref is None
                    or frame_num in (self._prev_ref, (self._prev_ref + 1) % (1 << info.log2_max_frame_num))
                )
                if ref_idc:
                    self._prev_ref = frame_num
                return follows  # the first slice speaks for its picture
        return True
