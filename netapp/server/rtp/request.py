"""What a robot asks for when it opens an RTP session (INIT's or /register's `rtp` argument), checked, and what it
is answered (the port, the SSRC to send with, the SDP a sender needs): pure functions, no I/O."""

from __future__ import annotations

import ipaddress
import json
from dataclasses import dataclass
from typing import Any

from netapp.protocol import RTP_TRANSPORT
from netapp.rtp.packet import DEFAULT_PAYLOAD_TYPE, H264_CLOCK_HZ

# In INIT's data: {"payload_type": 96, "address": "10.0.0.7", "rtcp_port": 5001, "rtcp_mux": false, "results": false};
# its answer's key
RTP_FIELD = RTP_TRANSPORT
MAX_REQUEST_BYTES = 512  # the `rtp` argument as JSON: a few numbers and an address
FIELDS = frozenset({"payload_type", "address", "rtcp_port", "rtcp_mux", "results"})
BAD_RTP_REASON = "bad_rtp"
PORTS_FULL_REASON = "rtp_ports_full"


@dataclass(frozen=True)
class RtpRequest:
    payload_type: int = DEFAULT_PAYLOAD_TYPE
    address: str | None = None  # the sender's IP the robot declares; None: the first sender's is kept
    rtcp_port: int | None = None  # where PLI goes; None: the sender's port + 1, or its own with rtcp_mux
    rtcp_mux: bool = False
    # Each result also goes back over UDP, in an RTCP APP packet (`RESULT_APP`) to the RTCP address: a lost one costs
    # nothing, the session's transport carries it too, but the first copy to arrive is not held behind TCP's losses.
    results: bool = False


def parse_request(value: Any) -> RtpRequest:
    """The `rtp` argument -> RtpRequest; ValueError saying what to send instead."""
    if value is True or value == {}:
        return RtpRequest()
    if not isinstance(value, dict):
        raise ValueError('rtp must be an object such as {"payload_type": 96} (or true)')
    try:
        size = len(json.dumps(value))
    except (TypeError, ValueError):
        size = MAX_REQUEST_BYTES + 1
    if size > MAX_REQUEST_BYTES:
        fields = ", ".join(sorted(FIELDS))
        raise ValueError(f"rtp is {size} bytes of JSON, over {MAX_REQUEST_BYTES}: send only {fields}")
    unknown = set(value) - FIELDS
    if unknown:
        raise ValueError(f"rtp has unknown fields {sorted(unknown)[:4]}: it takes {', '.join(sorted(FIELDS))}")
    pt = value.get("payload_type", DEFAULT_PAYLOAD_TYPE)
    if not _integer(pt) or not 96 <= pt <= 127:
        raise ValueError(f"rtp payload_type must be a dynamic payload type, 96 to 127, got {str(pt)[:20]}")
    address = value.get("address")
    if address is not None:
        try:
            address = str(ipaddress.ip_address(address))
        except ValueError:
            raise ValueError(f"rtp address must be an IP address, got {str(address)[:40]!r}") from None
    rtcp_port = value.get("rtcp_port")
    if rtcp_port is not None and (not _integer(rtcp_port) or not 1 <= rtcp_port <= 65535):
        raise ValueError(f"rtp rtcp_port must be a port, 1 to 65535, got {str(rtcp_port)[:20]}")
    mux = value.get("rtcp_mux", False)
    if not isinstance(mux, bool):
        raise ValueError("rtp rtcp_mux must be true or false")
    results = value.get("results", False)
    if not isinstance(results, bool):
        raise ValueError("rtp results must be true or false")
    return RtpRequest(pt, address, rtcp_port, mux, results)


def _integer(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def answer(request: RtpRequest, host: str, port: int, ssrc: int) -> dict[str, Any]:
    """What the robot is told: send H.264 (RFC 6184, packetization-mode 1) to `host`:`port` with this SSRC."""
    return {"port": port, "ssrc": ssrc, "payload_type": request.payload_type, "sdp": sdp(host, port, request, ssrc)}


def sdp(host: str, port: int, request: RtpRequest, ssrc: int) -> str:
    """The session description (RFC 8866) of the stream the netapp receives."""
    family = "IP6" if ":" in host else "IP4"
    pt = request.payload_type
    lines = [
        "v=0",
        f"o=- {ssrc} 1 IN {family} {host}",
        "s=netapp",
        f"c=IN {family} {host}",
        "t=0 0",
        f"m=video {port} RTP/AVP {pt}",
        f"a=rtpmap:{pt} H264/{H264_CLOCK_HZ}",
        f"a=fmtp:{pt} packetization-mode=1",
        f"a=ssrc:{ssrc} cname:netapp",
        "a=rtcp-fb:* nack pli",
        "a=recvonly",
    ]
    if request.rtcp_mux:
        lines.append("a=rtcp-mux")
    return "\r\n".join(lines) + "\r\n"
