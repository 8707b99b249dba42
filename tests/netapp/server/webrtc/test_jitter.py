"""The video jitter buffer releases a picture at its marker bit (aiortc's own waits for the next picture's first
packet: a frame interval), and never with a packet missing."""

from __future__ import annotations

import pytest

pytest.importorskip("aiortc", reason="aiortc is not installed: pip install 'netapp-toolkit[webrtc]'")

from aiortc.rtp import RtpPacket  # noqa: E402

from netapp.server.webrtc.jitter import marker_jitter_buffer  # noqa: E402


def packet(sequence: int, timestamp: int, data: bytes, marker: bool = False) -> RtpPacket:
    p = RtpPacket(payload_type=96, sequence_number=sequence, timestamp=timestamp, marker=int(marker))
    p._data = data  # what aiortc's receiver sets: the depayloaded bytes
    return p


def test_a_picture_is_released_at_its_last_packet():
    buffer = marker_jitter_buffer()(capacity=128, is_video=True)
    assert buffer.add(packet(10, 9000, b"a"))[1] is None
    _, frame = buffer.add(packet(11, 9000, b"b", marker=True))
    assert frame is not None and (frame.data, frame.timestamp) == (b"ab", 9000)
    _, frame = buffer.add(packet(12, 18000, b"c", marker=True))
    assert frame is not None and frame.data == b"c"


def test_a_picture_with_a_packet_missing_waits_for_it():
    buffer = marker_jitter_buffer()(capacity=128, is_video=True)
    assert buffer.add(packet(20, 9000, b"a"))[1] is None
    assert buffer.add(packet(22, 9000, b"c", marker=True))[1] is None  # 21 lost: nothing yet
    _, frame = buffer.add(packet(21, 9000, b"b"))  # sent again (NACK)
    assert frame is not None and frame.data == b"abc"
