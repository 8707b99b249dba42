"""The offer's checks and the ICE settings, pure: each bound refused with its reason before aiortc sees the SDP."""

from __future__ import annotations

import pytest

from netapp.server.errors import RequestRefused
from netapp.server.webrtc.offer import MAX_MEDIA, check_offer
from netapp.webrtc_ice import ice_addresses_for, parse_ice_server

GOOD = (
    "v=0\r\no=- 1 2 IN IP4 127.0.0.1\r\ns=-\r\nt=0 0\r\nm=video 9 UDP/TLS/RTP/SAVPF 96\r\n"
    "m=application 9 UDP/DTLS/SCTP webrtc-datachannel\r\n"
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
