"""The RTP session's pure parts: its request, its answer (SDP), its port range, and its gate (`Flow`)."""

from __future__ import annotations

import pytest

from netapp.rtp.packet import build
from netapp.server.rtp.flow import Flow
from netapp.server.rtp.ports import PortPool, parse_port_range
from netapp.server.rtp.request import MAX_REQUEST_BYTES, RtpRequest, answer, parse_request

ROBOT, STRANGER = ("10.0.0.7", 5000), ("10.0.0.9", 6000)


def datagram(ssrc: int = 42, payload_type: int = 96, size: int = 100) -> bytes:
    return build(
        b"\x65" + b"\x00" * (size - 13), payload_type=payload_type, sequence=1, timestamp=1, ssrc=ssrc, marker=True
    )


def test_a_request_takes_its_fields_and_refuses_anything_else():
    assert parse_request(True) == parse_request({}) == RtpRequest()
    assert parse_request({"payload_type": 100, "address": "10.0.0.7", "rtcp_port": 5001}) == RtpRequest(
        100, "10.0.0.7", 5001, False
    )


@pytest.mark.parametrize(
    ("value", "says"),
    [
        ("yes", "must be an object"),
        ({"payload_type": 0}, "96 to 127"),
        ({"payload_type": True}, "96 to 127"),
        ({"address": "camera.local"}, "IP address"),
        ({"rtcp_port": 70000}, "1 to 65535"),
        ({"rtcp_mux": "yes"}, "true or false"),
        ({"results": 1}, "true or false"),
        ({"sdp": "x"}, "unknown fields"),
        ({"address": "1" * (MAX_REQUEST_BYTES * 100)}, f"over {MAX_REQUEST_BYTES}"),
        ({"payload_type": [96] * 10_000}, f"over {MAX_REQUEST_BYTES}"),
    ],
)
def test_absurd_requests_are_refused_in_one_line(value, says):
    with pytest.raises(ValueError, match=says) as error:
        parse_request(value)
    assert len(str(error.value)) < 200


def test_the_answer_carries_the_port_the_ssrc_and_an_sdp():
    got = answer(RtpRequest(rtcp_mux=True), "192.0.2.1", 50000, 99)
    assert (got["port"], got["ssrc"], got["payload_type"]) == (50000, 99, 96)
    assert "m=video 50000 RTP/AVP 96\r\n" in got["sdp"] and "a=rtpmap:96 H264/90000" in got["sdp"]
    assert "c=IN IP4 192.0.2.1" in got["sdp"] and "a=ssrc:99 " in got["sdp"] and "a=rtcp-mux" in got["sdp"]


@pytest.mark.parametrize("text", ["5000-", "x-y", "60000-50000", "80-90", "10000-20000"])
def test_bad_port_ranges_say_what_to_write(text):
    with pytest.raises(ValueError, match="--rtp-ports"):
        parse_port_range(text)


def test_ports_are_handed_out_lowest_first_and_returned():
    pool = PortPool(parse_port_range("50000-50002"))
    pool.hold(pool.candidates()[0])
    assert pool.candidates() == [50001, 50002] and pool.free == 2
    pool.give_back(50000)
    assert pool.candidates()[0] == 50000 and pool.free == 3


def flow(**request) -> Flow:
    return Flow(RtpRequest(**request), 42, max_packets_per_s=100, max_bytes_per_s=100_000)


def test_the_first_sender_with_the_ssrc_is_bound_and_strangers_are_dropped():
    gate = flow()
    assert gate.admit(datagram(ssrc=1), STRANGER, 0.0) == "wrong_ssrc"  # a guessed port without the token binds nothing
    assert gate.sender is None
    assert not isinstance(gate.admit(datagram(), ROBOT, 0.0), str) and gate.sender == ROBOT
    assert gate.admit(datagram(), STRANGER, 0.0) == "stranger"  # even with the right SSRC
    assert gate.rtcp_address() == ("10.0.0.7", 5001)


def test_a_declared_address_is_the_only_one_taken():
    gate = flow(address="10.0.0.7", rtcp_mux=True)
    assert gate.admit(datagram(), STRANGER, 0.0) == "stranger" and gate.sender is None
    assert not isinstance(gate.admit(datagram(), ROBOT, 0.0), str) and gate.rtcp_address() == ROBOT


def test_wrong_payload_types_rtcp_and_malformed_datagrams_are_dropped_with_their_reason():
    gate = flow()
    assert gate.admit(datagram(payload_type=97), ROBOT, 0.0) == "wrong_payload_type"
    assert gate.admit(b"\x81\xc9\x00\x01" + b"\x00" * 4, ROBOT, 0.0) == "rtcp"
    assert gate.admit(b"\x00" * 12, ROBOT, 0.0) == "malformed"
    assert gate.admit(b"\x80" * 2000, ROBOT, 0.0) == "too_large"
    assert gate.sender is None


def test_a_flood_is_dropped_past_the_packet_and_byte_rates_and_the_rate_comes_back():
    gate = flow()
    results = [gate.admit(datagram(), ROBOT, 0.0) for _ in range(150)]
    assert sum(r == "flood" for r in results) == 50  # a second's worth at once, no more
    assert not isinstance(gate.admit(datagram(), ROBOT, 1.0), str)  # a second later
    big = Flow(RtpRequest(), 42, max_packets_per_s=10_000, max_bytes_per_s=10_000)
    assert sum(big.admit(datagram(size=1000), ROBOT, 5.0) == "flood" for _ in range(20)) == 10
