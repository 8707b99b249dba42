"""Packets back in order, a gap asked for again (RTCP generic NACK) and given up after its hold; NACKs written and
read back, bounded."""

from __future__ import annotations

from netapp.rtp.packet import RtpPacket, build, is_rtcp, nack, parse_nack
from netapp.rtp.reorder import HOLD_S, RENACK_S, Reorder


def packet(sequence: int) -> RtpPacket:
    return RtpPacket(False, 96, sequence & 0xFFFF, 0, 1, b"\x65")


def sequences(packets) -> list[int]:
    return [p.sequence for p in packets]


def test_a_gap_is_asked_for_and_filled_in_order():
    reorder = Reorder()
    assert sequences(reorder.push(packet(10), 0.0)[0]) == [10]
    ready, asked = reorder.push(packet(13), 0.001)
    assert ready == [] and asked == [11, 12]
    assert reorder.push(packet(12), 0.002) == ([], [])  # held: 11 still missing
    ready, asked = reorder.push(packet(11), 0.04)
    assert sequences(ready) == [11, 12, 13] and reorder.next_deadline() is None
    assert reorder.push(packet(12), 0.05) == (None, [])  # a duplicate (late)


def test_a_gap_is_asked_again_then_given_up_after_its_hold():
    reorder = Reorder()
    reorder.push(packet(65535), 0.0)
    assert reorder.push(packet(1), 0.0) == ([], [0])  # across the wrap
    assert reorder.tick(RENACK_S) == ([], [0])
    assert reorder.next_deadline() is not None
    ready, _ = reorder.tick(HOLD_S)
    assert sequences(ready) == [1] and reorder.next_deadline() is None
    assert reorder.push(packet(0), HOLD_S + 0.01) == (None, [])  # too late now: the depacketiser saw the loss


def test_what_is_held_is_bounded():
    reorder = Reorder(max_held=8)
    reorder.push(packet(0), 0.0)
    for s in range(2, 11):
        ready, _ = reorder.push(packet(s), 0.0)
    assert sequences(ready) == list(range(2, 11))  # past 8 held, the gap is given up at once


def test_nack_reads_back_and_a_hostile_one_is_bounded():
    data = nack(1, 2, [5, 6, 9, 21, 22, 40])
    assert is_rtcp(data) and sorted(parse_nack(data)) == [5, 6, 9, 21, 22, 40]
    assert parse_nack(build(b"x", payload_type=96, sequence=1, timestamp=1, ssrc=1, marker=True)) == []
    huge = data[:2] + b"\xff\xff" + data[4:12] + b"\x00\x01\xff\xff" * 10_000
    assert len(parse_nack(huge)) <= 64 * 17
    assert parse_nack(b"\x81\xcd\x00") == []
