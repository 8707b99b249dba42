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


VP8_KEY = b"\x10\x02\x00\x9d\x01\x2a" + b"k" * 10  # frame tag (key, shown), start code
VP8_INTER = b"\x31\x02\x00" + b"i" * 10


def test_after_aiortc_drops_pictures_none_goes_to_the_decoder_before_a_keyframe():
    held = []
    buffer = marker_jitter_buffer()(capacity=16, is_video=True)
    type(buffer).on_skipped = lambda: held.append(1)
    assert buffer.add(packet(100, 0, VP8_KEY, marker=True))[1].data == VP8_KEY
    assert buffer.add(packet(101, 3000, b"\x31", marker=False))[1] is None
    # 102 never comes; 16 packets later aiortc gives up on it, drops what is before, and asks for a keyframe
    asked_any, released = False, []
    for n in range(103, 103 + 16):
        asked, frame = buffer.add(packet(n, 3000 * (n - 100), VP8_INTER, marker=True))
        asked_any |= asked
        released += [frame] if frame is not None else []
    assert asked_any and not released and held  # inter pictures refer to the lost one: held back, counted
    # the keyframe asked for comes; aiortc releases one picture an added packet, so the backlog drains as more come
    after = [buffer.add(packet(119, 3000 * 19, VP8_KEY, marker=True))[1]]
    after += [buffer.add(packet(n, 3000 * (n - 100), VP8_INTER, marker=True))[1] for n in range(120, 134)]
    released = [f.data for f in after if f is not None]
    assert released and released[0] == VP8_KEY  # the keyframe first; what follows it goes on
    assert not buffer._waiting_keyframe


def test_keyframes_are_told_apart():
    from netapp.server.webrtc.jitter import is_keyframe

    assert is_keyframe(VP8_KEY) and not is_keyframe(VP8_INTER)
    assert is_keyframe(b"\x00\x00\x00\x01\x67\x42\x00\x00\x00\x01\x68\x00\x00\x01\x65")  # SPS, PPS, IDR
    assert not is_keyframe(b"\x00\x00\x00\x01\x41\x9a")  # a P slice
    assert not is_keyframe(b"")


def test_a_packet_still_missing_after_a_while_is_given_up_and_a_keyframe_asked_for(monkeypatch):
    from netapp.server.webrtc import jitter

    clock = [100.0]
    monkeypatch.setattr(jitter.time, "monotonic", lambda: clock[0])
    buffer = marker_jitter_buffer()(capacity=512, is_video=True)
    assert buffer.add(packet(1, 0, VP8_KEY, marker=True))[1].data == VP8_KEY
    # packet 2 (a whole picture) is lost, and so is its retransmission
    assert buffer.add(packet(3, 6000, VP8_INTER, marker=True)) == (False, None)
    clock[0] += jitter.GIVE_UP_S / 2
    assert buffer.add(packet(4, 9000, VP8_INTER, marker=True)) == (False, None)  # still hoping for it
    clock[0] += jitter.GIVE_UP_S
    asked, frame = buffer.add(packet(5, 12000, VP8_INTER, marker=True))
    assert asked and frame is None  # given up long before aiortc's 512 packets: a keyframe asked for
    released = [buffer.add(packet(n, 3000 * n, VP8_INTER, marker=True))[1] for n in (6, 7)]
    assert released == [None, None]  # pictures after the loss refer to it: held
    after = [buffer.add(packet(n, 3000 * n, VP8_KEY if n == 8 else VP8_INTER, marker=True))[1] for n in range(8, 16)]
    assert [f.data for f in after if f is not None][0] == VP8_KEY


def vp8_key(width: int, height: int) -> bytes:
    """A VP8 key frame's header (RFC 6386 9.1): frame tag, start code, 14-bit width and height."""
    return b"\x10\x02\x00" + b"\x9d\x01\x2a" + width.to_bytes(2, "little") + height.to_bytes(2, "little") + b"\0" * 8


def test_a_picture_claiming_more_than_the_bound_never_reaches_the_decoder():
    from netapp.server.webrtc.jitter import claimed_size

    assert claimed_size(vp8_key(7680, 4320)) == (7680, 4320) and claimed_size(VP8_INTER) is None
    told = []
    buffer = marker_jitter_buffer()(capacity=128, is_video=True)
    buffer.bound(640 * 480, lambda w, h, pts: told.append((w, h, pts)))
    assert buffer.add(packet(1, 3000, vp8_key(7680, 4320), marker=True))[1] is None
    assert buffer.add(packet(2, 6000, VP8_INTER, marker=True))[1] is None  # refers to it: held
    assert told == [(7680, 4320, 3000)]
    assert buffer.add(packet(3, 9000, vp8_key(640, 480), marker=True))[1].data == vp8_key(640, 480)
    assert buffer.add(packet(4, 12000, VP8_INTER, marker=True))[1].data == VP8_INTER
