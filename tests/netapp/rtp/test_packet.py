"""RTP headers read and written (RFC 3550), PLI (RFC 4585), hostile datagrams refused with their reason."""

from __future__ import annotations

import struct

import pytest

from netapp.rtp.packet import (
    MAX_APP_DATA_BYTES,
    MAX_DATAGRAM_BYTES,
    RESULT_APP,
    RtpError,
    app,
    build,
    is_rtcp,
    nack,
    parse,
    parse_app,
    pli,
    sequence_after,
    unwrap_timestamp,
)


def test_a_packet_reads_back_as_built():
    packet = parse(build(b"\x65abc", payload_type=96, sequence=65535, timestamp=2**32 - 1, ssrc=7, marker=True))
    assert (packet.marker, packet.payload_type, packet.sequence, packet.timestamp, packet.ssrc, packet.payload) == (
        True,
        96,
        65535,
        2**32 - 1,
        7,
        b"\x65abc",
    )


def test_csrcs_an_extension_and_padding_are_skipped():
    header = struct.pack("!BBHII", 0x80 | 0x20 | 0x10 | 2, 96, 1, 2, 3) + b"C" * 8  # 2 CSRCs
    extension = struct.pack("!HH", 0xBEDE, 1) + b"E" * 4
    packet = parse(header + extension + b"\x65pay" + b"\x00\x00\x03")
    assert packet.payload == b"\x65pay"


@pytest.mark.parametrize(
    ("datagram", "reason"),
    [
        (b"\x80" * 11, "malformed"),
        (struct.pack("!BBHII", 0x40, 96, 1, 2, 3), "malformed"),  # version 1
        (struct.pack("!BBHII", 0x8F, 96, 1, 2, 3), "malformed"),  # 15 CSRCs in a bare header
        (struct.pack("!BBHII", 0x90, 96, 1, 2, 3) + b"\xbe\xde", "malformed"),  # an extension header cut short
        (struct.pack("!BBHII", 0x90, 96, 1, 2, 3) + struct.pack("!HH", 0, 0xFFFF), "malformed"),  # its length
        (struct.pack("!BBHII", 0xA0, 96, 1, 2, 3) + b"\x65\x00", "malformed"),  # padding count 0
        (struct.pack("!BBHII", 0xA0, 96, 1, 2, 3) + b"\x65\xff", "malformed"),  # padding past the header
        (b"\x80" * (MAX_DATAGRAM_BYTES + 1), "too_large"),
    ],
)
def test_hostile_datagrams_are_refused_with_their_reason(datagram, reason):
    with pytest.raises(RtpError) as error:
        parse(datagram)
    assert error.value.reason == reason


def test_pli_is_rtcp_payload_specific_feedback():
    data = pli(1, 2)
    assert is_rtcp(data) and data[1] == 206 and data[0] & 0x1F == 1 and len(data) == 12
    assert not is_rtcp(build(b"x", payload_type=96, sequence=0, timestamp=0, ssrc=0, marker=True))


def test_sequence_distance_wraps():
    assert sequence_after(65535, 0) == 1 and sequence_after(0, 65535) == -1 and sequence_after(5, 5) == 0


def test_a_timestamp_is_unwrapped_past_32_bits_both_ways():
    assert unwrap_timestamp(None, 7) == 7
    assert unwrap_timestamp(0xFFFFFF00, 0x100) == 0x1_0000_0100  # forward over the wrap
    assert unwrap_timestamp(0x1_0000_0100, 0xFFFFFF00) == 0xFFFFFF00  # a late picture from before it
    assert unwrap_timestamp(3000, 6000) == 6000


def test_an_app_packet_carries_a_result_and_a_hostile_one_is_refused():
    data = app(0xABCD, RESULT_APP, b'{"timestamp":1}')
    assert is_rtcp(data) and len(data) % 4 == 0
    ssrc, body = parse_app(data, RESULT_APP)
    assert ssrc == 0xABCD and body.rstrip() == b'{"timestamp":1}'
    assert parse_app(data, b"XXXX") is None  # another application's
    assert parse_app(data[:-4], RESULT_APP) is None  # its length field says more than came
    assert parse_app(data + b"    ", RESULT_APP) is None
    assert parse_app(build(b"x", payload_type=96, sequence=1, timestamp=1, ssrc=1, marker=True), RESULT_APP) is None
    assert parse_app(nack(1, 2, [5]), RESULT_APP) is None and parse_app(b"\x80\xcc", RESULT_APP) is None
    app(1, RESULT_APP, b"x" * MAX_APP_DATA_BYTES)  # one datagram's worth fits, one byte more does not
    with pytest.raises(ValueError, match="at most"):
        app(1, RESULT_APP, b"x" * (MAX_APP_DATA_BYTES + 1))
