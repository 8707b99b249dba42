"""The H.264 RTP depacketiser (RFC 6184) and the project's packetiser: real x264 access units through both, and
hostile packets, each discarded with its reason and never handed on as a picture."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from netapp.rtp.depacketize import FU_A, STAP_A, START_CODE, Depacketizer, starts_access_unit
from netapp.rtp.packet import RtpPacket
from netapp.rtp.packetize import payloads, split_annex_b

SSRC = 1234


def packets(units: list[bytes], first_sequence: int = 0, max_payload: int = 1400) -> list[RtpPacket]:
    """Each access unit's RTP packets, 3000 ticks apart (10 fps at 90 kHz), the last with the marker."""
    out: list[RtpPacket] = []
    sequence = first_sequence
    for k, unit in enumerate(units):
        pieces = list(payloads(unit, max_payload))
        for i, piece in enumerate(pieces):
            out.append(RtpPacket(i == len(pieces) - 1, 96, sequence & 0xFFFF, 3000 * k, SSRC, piece))
            sequence += 1
    return out


@pytest.fixture(scope="module")
def stream() -> list[tuple[bytes, bool]]:
    """12 real x264 access units (a keyframe every 6), 320x240: (Annex B bytes, keyframe)."""
    pytest.importorskip("av", reason="PyAV is not installed: pip install 'netapp-toolkit[h264]'")
    from netapp.client.h264 import H264Encoder

    encoder = H264Encoder(320, 240, {"g": "6"})
    rng = np.random.default_rng(1)
    units = []
    for _ in range(12):
        data, keyframe = encoder.encode(rng.integers(0, 255, (240, 320, 3), dtype=np.uint8))
        units.append((data, keyframe))
    encoder.close()
    return units


def run(depacketizer: Depacketizer, items: list[RtpPacket]) -> tuple[list, list[str]]:
    units, problems = [], []
    for packet in items:
        got, why = depacketizer.push(packet)
        units += got
        problems += why
    return units, problems


def normalised(annex_b: bytes) -> bytes:
    return b"".join(START_CODE + nal for nal in split_annex_b(annex_b))


def test_real_access_units_come_back_whole_through_fragments(stream):
    items = packets([data for data, _ in stream])
    assert any(p.payload[0] & 0x1F == FU_A for p in items)  # noise pictures are larger than one packet
    units, problems = run(Depacketizer(), items)
    assert problems == []
    assert [u.data for u in units] == [normalised(data) for data, _ in stream]
    assert [u.keyframe for u in units] == [k for _, k in stream] and units[0].keyframe


def test_a_lost_packet_loses_the_pictures_until_the_next_keyframe_and_no_more(stream):
    items = packets([data for data, _ in stream])
    lost = next(i for i, p in enumerate(items) if p.timestamp == 3000 * 2)  # the third picture's first packet
    depacketizer = Depacketizer()
    units, problems = run(depacketizer, items[:lost] + items[lost + 1 :])
    times = [u.rtp_timestamp for u in units]
    assert times == [0, 3000, *(3000 * k for k in range(6, 12))]  # 2..5 discarded: they reference the lost one
    assert "gap" in problems and problems.count("waiting_keyframe") == 3
    assert not depacketizer.need_keyframe


def test_sequence_numbers_wrap_and_duplicates_are_dropped_alone(stream):
    items = packets([data for data, _ in stream[:6]], first_sequence=65530)
    doubled = [x for p in items for x in (p, p)]
    units, problems = run(Depacketizer(), doubled)
    assert len(units) == 6 and set(problems) == {"late"} and len(problems) == len(items)


def test_an_access_unit_without_its_marker_ends_when_the_timestamp_moves(stream):
    items = packets([data for data, _ in stream[:3]])
    unmarked = [RtpPacket(False, p.payload_type, p.sequence, p.timestamp, p.ssrc, p.payload) for p in items]
    units, problems = run(Depacketizer(), unmarked)
    assert [u.rtp_timestamp for u in units] == [0, 3000] and problems == []


def test_joining_in_the_middle_of_a_picture_waits_for_a_whole_keyframe(stream):
    items = packets([data for data, _ in stream])
    middle = next(i for i, p in enumerate(items) if p.payload[0] & 0x1F == FU_A and not p.payload[1] & 0x80)
    assert items[middle].timestamp == 0
    units, problems = run(Depacketizer(), items[middle:])  # the keyframe's first packets never came
    assert units[0].rtp_timestamp == 3000 * 6 and units[0].keyframe
    assert problems[0] in {"malformed", "incomplete"}


def nal(kind: int, body: bytes = b"\x88\x84") -> bytes:
    return bytes([0x60 | kind]) + body


IDR = nal(5)
KEYFRAME = (nal(7), nal(8), IDR)  # a stream's first keyframe carries its parameter sets (SPS, PPS)


def stap(*nals: bytes) -> bytes:
    return bytes([STAP_A]) + b"".join(struct.pack("!H", len(n)) + n for n in nals)


def one(payload: bytes, sequence: int = 0, marker: bool = True, timestamp: int = 0) -> RtpPacket:
    return RtpPacket(marker, 96, sequence, timestamp, SSRC, payload)


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (b"", "malformed"),
        (b"\x80", "malformed"),  # forbidden_zero_bit
        (bytes([STAP_A]) + b"\x00", "malformed"),  # a size cut short
        (bytes([STAP_A]) + struct.pack("!H", 50) + IDR, "malformed"),  # a size past the packet
        (bytes([STAP_A]) + struct.pack("!H", 0), "malformed"),
        (bytes([FU_A, 0x05]) + b"\x88", "malformed"),  # a middle piece without its start
        (bytes([FU_A]), "malformed"),
        (bytes([0x60 | 25]) + IDR, "malformed"),  # STAP-B: interleaved mode, refused
        (bytes([0x60 | 29]) + b"\x85\x88", "malformed"),  # FU-B
        (bytes([FU_A, 0x85]) + b"\x88\x84", "malformed"),  # the marker inside a fragmented NAL unit
    ],
)
def test_hostile_payloads_are_discarded_with_their_reason(payload, reason):
    depacketizer = Depacketizer()
    units, problems = depacketizer.push(one(payload))
    assert units == [] and problems == [reason] and depacketizer.need_keyframe
    units, problems = depacketizer.push(one(stap(*KEYFRAME), sequence=1, timestamp=3000))  # and the stream goes on
    assert [u.data for u in units] == [b"".join(START_CODE + n for n in KEYFRAME)] and problems == []


def test_an_access_unit_over_its_bound_is_discarded_before_it_grows():
    depacketizer = Depacketizer(max_access_unit_bytes=4096)
    start = one(bytes([FU_A, 0x80 | 5]) + b"\x88" * 1400, marker=False)
    middles = [one(bytes([FU_A, 5]) + b"\x00" * 1400, sequence=k, marker=False) for k in range(1, 10)]
    units, problems = run(depacketizer, [start, *middles, one(bytes([FU_A, 0x40 | 5]) + b"\x00", sequence=10)])
    assert units == [] and problems == ["too_large"]
    assert depacketizer._bytes == 0 and depacketizer._fragment is None  # nothing held past the bound


def test_an_access_unit_with_too_many_nal_units_is_discarded():
    stap = bytes([STAP_A]) + b"".join(struct.pack("!H", len(IDR)) + IDR for _ in range(300))
    units, problems = Depacketizer(max_nals=256).push(one(stap))
    assert units == [] and problems == ["too_many_nals"]


def test_a_first_keyframe_without_its_parameter_sets_is_incomplete_and_a_keyframe_asked_for(stream):
    items = packets([data for data, _ in stream])
    assert items[0].payload[0] & 0x1F == 7  # the stream's first packet is its SPS
    depacketizer = Depacketizer()
    units, problems = run(depacketizer, items[1:])  # lost: no gap (nothing came before it), yet no decoder opens
    assert problems[:1] == ["incomplete"] and depacketizer.discarded[:1] == [0]  # told, as any skipped picture
    assert units[0].rtp_timestamp == 3000 * 6 and units[0].keyframe  # the next keyframe, with its SPS, goes on
    assert not depacketizer.need_keyframe
    later, _ = run(depacketizer, [one(IDR, sequence=items[-1].sequence + 1, timestamp=3000 * 12)])
    assert later and later[0].keyframe  # once a stream's parameter sets came, a keyframe needs none of its own


def test_an_access_unit_begins_only_with_a_parameter_set_or_a_first_slice():
    assert starts_access_unit(nal(7)) and starts_access_unit(nal(5, b"\x88")) and starts_access_unit(nal(9))
    assert not starts_access_unit(nal(5, b"\x48"))  # first_mb_in_slice > 0: a later slice of its picture
    assert not starts_access_unit(nal(1, b"\x00"))


def test_a_picture_whose_end_never_comes_expires_and_is_reported(stream):
    items = packets([data for data, _ in stream[:2]])
    depacketizer = Depacketizer()
    units, _ = run(depacketizer, items[:-1])  # the second picture's last packet (its marker) is lost
    assert [u.rtp_timestamp for u in units] == [0] and depacketizer.gathering
    assert depacketizer.expire() == "timeout" and depacketizer.discarded == [3000]
    assert not depacketizer.gathering and depacketizer.need_keyframe and depacketizer.expire() is None


def test_each_discarded_picture_is_named_by_its_timestamp(stream):
    items = packets([data for data, _ in stream])
    lost = next(i for i, p in enumerate(items) if p.timestamp == 3000 * 2)
    depacketizer = Depacketizer()
    run(depacketizer, items[:lost] + items[lost + 1 :])
    assert depacketizer.discarded == [3000 * k for k in range(2, 6)]
