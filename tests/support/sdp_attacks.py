"""Offers aiortc would answer and never connect, made from a real offer, and ICE candidates at addresses the offer
did not come from: for tests and benchmarks (issue 45)."""

from __future__ import annotations

import re

BROKEN = {  # what aiortc answered and then waited out the connect timeout for (issue 45)
    "no fingerprint": lambda sdp: re.sub(r"a=fingerprint:[^\r]*\r\n", "", sdp),
    "a bad c-line": lambda sdp: sdp.replace("c=IN IP4 127.0.0.1", "c=IN IP4 nowhere", 1),
    "port 99999999": lambda sdp: re.sub(r"m=video \d+", "m=video 99999999", sdp),
    "NUL bytes": lambda sdp: sdp.replace("s=-", "s=\x00\x00"),
    "payload type 2^32": lambda sdp: sdp.replace("a=rtpmap:97 ", "a=rtpmap:4294967296 "),
    "300 extmaps": lambda sdp: sdp.replace("a=sendrecv", "a=sendrecv" + "\r\na=extmap:5 urn:x" * 300, 1),
    "a UTF-8 bomb": lambda sdp: sdp.replace("s=-", "s=" + "\U0001f4a3" * 1000),
}


def foreign_candidates(count: int) -> str:
    """`count` host candidates at documentation addresses (TEST-NET-3): none is the offer's own."""
    return "".join(f"a=candidate:{n} 1 udp 2130706431 203.0.113.{n % 250 + 1} 9 typ host\r\n" for n in range(count))
