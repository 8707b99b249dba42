"""The offer's checks and the ICE settings, pure: each bound refused with its reason before aiortc sees the SDP."""

from __future__ import annotations

import pytest

from netapp.server.errors import RequestRefused
from netapp.server.webrtc.offer import MAX_CANDIDATES, MAX_MEDIA, canonical_address, check_offer, keep_candidates
from netapp.webrtc_ice import ice_addresses_for, parse_ice_server

FINGERPRINT = "a=fingerprint:sha-256 " + ":".join(["AB"] * 32)
ICE = "a=ice-ufrag:RI2b\r\na=ice-pwd:bduOVSwjdzdIt8vdBklkf4\r\n"
CANDIDATE = "a=candidate:1 1 udp 2130706431 {} 37336 typ host\r\n"
GOOD = (
    f"v=0\r\no=- 1 2 IN IP4 127.0.0.1\r\ns=-\r\nt=0 0\r\n{FINGERPRINT}\r\n{ICE}m=video 9 UDP/TLS/RTP/SAVPF 96\r\n"
    "c=IN IP4 192.0.2.2\r\na=rtpmap:96 VP8/90000\r\na=extmap:1 urn:ietf:params:rtp-hdrext:sdes:mid\r\n"
    + CANDIDATE.format("192.0.2.2")
    + "m=application 9 UDP/DTLS/SCTP webrtc-datachannel\r\n"
)


def refused(body, **bounds) -> RequestRefused:
    with pytest.raises(RequestRefused) as caught:
        check_offer(body, **bounds)
    return caught.value


def test_a_good_offer_is_taken():
    offer = check_offer({"type": "offer", "sdp": GOOD, "robot_id": "phone"})
    assert offer.robot_id == "phone" and offer.data_channel


@pytest.mark.parametrize(
    ("body", "reason", "status"),
    [
        ({"type": "offer", "sdp": GOOD + "a=x\r\n" * 5000}, "sdp_too_large", 413),
        ({"type": "offer", "sdp": "\x00\xff garbage"}, "bad_sdp", 400),
        ({"type": "offer", "sdp": "v=0\r\n<html>\r\n"}, "bad_sdp", 400),
        ({"type": "offer", "sdp": "v=0\r\na=" + "x" * 2000 + "\r\n"}, "bad_sdp", 400),
        ({"type": "answer", "sdp": GOOD}, "bad_sdp", 400),
        ([GOOD], "bad_sdp", 400),
        (None, "bad_sdp", 400),
        ({"type": "offer", "sdp": GOOD + "m=video 9 RTP/AVP 96\r\n" * MAX_MEDIA}, "too_many_media", 422),
        ({"type": "offer", "sdp": GOOD.replace("m=video", "m=audio")}, "no_video", 422),
        ({"type": "offer", "sdp": GOOD, "robot_id": "x" * 500}, "bad_sdp", 400),
    ],
)
def test_each_bad_offer_is_refused_saying_why(body, reason, status):
    error = refused(body)
    assert (error.reason, error.status) == (reason, status)
    assert str(error)


@pytest.mark.parametrize(
    ("change", "says"),
    [
        (lambda sdp: sdp.replace(FINGERPRINT, "a=x:y"), "no usable DTLS fingerprint"),
        (lambda sdp: sdp.replace(FINGERPRINT, "a=fingerprint:md5 AB:CD"), "no usable DTLS fingerprint"),
        (lambda sdp: sdp.replace(ICE, ""), "no usable ICE credentials"),
        (lambda sdp: sdp.replace("c=IN IP4 192.0.2.2", "c=IN IP4 999.1.1.1"), "no IN IP4 or IN IP6 address"),
        (lambda sdp: sdp.replace("c=IN IP4 192.0.2.2", "c=IN IP6 192.0.2.2"), "no IN IP4 or IN IP6 address"),
        (lambda sdp: sdp.replace("m=video 9 ", "m=video 99999999 "), "is no UDP port"),
        (lambda sdp: sdp.replace("t=0 0", "t=0 \x000"), "the character"),
        (lambda sdp: sdp.replace("SAVPF 96", "SAVPF 4294967296"), "payload types must be numbers"),
        (lambda sdp: sdp.replace("rtpmap:96", "rtpmap:4294967296"), "a payload type from 0 to 127"),
        (lambda sdp: sdp.replace("a=extmap:1 u", "a=extmap:1 u" * 1 + "\r\na=extmap:2 u" * 300), "a=extmap"),
        (lambda sdp: sdp.replace("a=extmap:1 ", "a=extmap:4096 "), "a=extmap"),
        (lambda sdp: sdp.replace("s=-", "s=" + "\u0301" * 1000), "printable ASCII"),
        (lambda sdp: sdp + CANDIDATE.format("10.0.0.1") * (MAX_CANDIDATES + 1), f"at most {MAX_CANDIDATES} ICE"),
    ],
)
def test_an_offer_aiortc_would_answer_and_never_connect_is_refused_at_once(change, says):
    error = refused({"type": "offer", "sdp": change(GOOD)})
    assert (error.reason, error.status) == ("bad_sdp", 400) and says in str(error), str(error)


def test_only_candidates_at_the_offers_own_address_are_kept():
    sdp = GOOD + CANDIDATE.format("10.0.0.9") + CANDIDATE.format("abc.local") + CANDIDATE.format("::ffff:192.0.2.2")
    kept, dropped = keep_candidates(sdp, frozenset({"192.0.2.2"}))
    assert dropped == 2 and kept.count("a=candidate:") == 2 and "10.0.0.9" not in kept and "abc.local" not in kept
    assert canonical_address("fe80::1%eth0") == "fe80::1" and canonical_address("cam.local") is None


def test_ice_servers_need_credentials_from_the_environment_never_the_url(tmp_path):
    assert parse_ice_server("stun:stun.example:3478", {}).username is None
    with pytest.raises(ValueError, match="NETAPP_ICE_USERNAME"):
        parse_ice_server("turn:turn.example:3478", {})
    with pytest.raises(ValueError, match="never in the URL"):
        parse_ice_server("turn:user:secret@turn.example", {})
    with pytest.raises(ValueError, match="stun:HOST"):
        parse_ice_server("http://turn.example", {})
    secret = tmp_path / "credential"
    secret.write_text("s3cret\n")
    env = {"NETAPP_ICE_USERNAME": "robot", "NETAPP_ICE_CREDENTIAL_FILE": str(secret)}
    server = parse_ice_server("turn:turn.example:3478?transport=tcp", env)
    assert (server.username, server.credential) == ("robot", "s3cret")
    assert "s3cret" not in repr(server)


def test_a_netapp_offers_candidates_on_the_address_it_listens_on():
    assert ice_addresses_for("127.0.0.1") == ("127.0.0.1",)
    assert ice_addresses_for("0.0.0.0") == ()
