"""An SDP offer, checked before aiortc parses it (pure): its size, its text, its m-lines. Every byte of it is the
caller's, so each bound is checked before the work it bounds, and each refusal has a reason the metrics count.

aiortc answers some offers it can never connect (no DTLS fingerprint, no ICE credentials, a port or payload type out
of range, a c-line that is no address, control or non-ASCII characters, hundreds of extmaps): such a peer would hold a
slot until the connect timeout. Each is refused here at once as `bad_sdp`, saying what is wrong (`sections_problem`).

The remote ICE candidates are the caller's too: the netapp would send connectivity checks to every address an offer
names. At most MAX_CANDIDATES are taken, and only those at the offer's own address (`keep_candidates`; from loopback,
this machine's addresses too): the others are dropped and counted, never checked.
"""

from __future__ import annotations

import ipaddress
import re
from dataclasses import dataclass
from typing import Any

from netapp.server.errors import RequestRefused

MAX_SDP_BYTES = 16 * 1024  # a browser's offer of one video and one data channel is 3 to 6 KB (Chromium: ~4.5 KB)
MAX_MEDIA = 4  # m-lines: the page and `netapp stream` offer two (video, application)
MAX_LINE_CHARS = 1024  # a line longer than this is no SDP a browser writes
MAX_ROBOT_ID_CHARS = 128
MAX_EXTMAPS = 32  # header extensions an m-line offers (Chromium: 13 for video)
MAX_PAYLOAD_TYPE = 127  # RTP's payload type is 7 bits
ICE_CHARS = re.compile(r"^[A-Za-z0-9+/]{4,256}$")  # RFC 8839's ice-char; a ufrag of 4, a password of 22 and up
FINGERPRINT = re.compile(r"^(?i:sha-1|sha-224|sha-256|sha-384|sha-512) [0-9A-Fa-f]{2}(?::[0-9A-Fa-f]{2}){15,63}$")
PAYLOAD_TYPED = ("a=rtpmap:", "a=fmtp:", "a=rtcp-fb:")
MAX_CANDIDATES = 32  # a=candidate lines in an offer (a browser's, bundled, with IPv6, STUN and TURN: about 12)
CANDIDATE = "a=candidate:"

# Reasons an offer is refused (`netapp_webrtc_refused{reason}`), each with its HTTP status
SDP_TOO_LARGE = "sdp_too_large"  # 413
BAD_SDP = "bad_sdp"  # 400
TOO_MANY_MEDIA = "too_many_media"  # 422
NO_VIDEO = "no_video"  # 422
PEERS_FULL = "peers_full"  # 503: --webrtc-peers held
CLIENT_PEERS_FULL = "client_peers_full"  # 429: one address holds its share
CONNECT_TIMEOUT = "connect_timeout"  # answered, but ICE/DTLS did not connect in time
NO_AIORTC = "no_aiortc"  # 501: the extra is not installed
REASONS = (SDP_TOO_LARGE, BAD_SDP, TOO_MANY_MEDIA, NO_VIDEO, PEERS_FULL, CLIENT_PEERS_FULL, CONNECT_TIMEOUT, NO_AIORTC)


@dataclass(frozen=True)
class Offer:
    sdp: str
    robot_id: str | None
    data_channel: bool  # an m=application line: results go back on it


def check_offer(body: Any, max_bytes: int = MAX_SDP_BYTES, max_media: int = MAX_MEDIA) -> Offer:
    """`{"type": "offer", "sdp": "...", "robot_id": ...}` (the body, parsed JSON) -> Offer; RequestRefused saying
    what is wrong."""
    if not isinstance(body, dict) or body.get("type", "offer") != "offer" or not isinstance(body.get("sdp"), str):
        raise RequestRefused(BAD_SDP, 'send JSON {"type": "offer", "sdp": "v=0..."}: an SDP offer (non-trickle)', 400)
    sdp: str = body["sdp"]
    if len(sdp) > max_bytes:
        raise RequestRefused(SDP_TOO_LARGE, f"an SDP of {len(sdp)} characters is over the {max_bytes} limit", 413)
    lines = sdp.splitlines()
    if not lines or lines[0].strip() != "v=0":
        raise RequestRefused(BAD_SDP, "this is no SDP: it must begin with v=0", 400)
    media = []
    for number, line in enumerate(lines, 1):
        if len(line) > MAX_LINE_CHARS:
            raise RequestRefused(BAD_SDP, f"SDP line {number} is over {MAX_LINE_CHARS} characters", 400)
        if line and (len(line) < 2 or line[1] != "=" or not line[0].isalpha()):
            raise RequestRefused(BAD_SDP, f"SDP line {number} is not TYPE=VALUE", 400)
        if line.startswith("m="):
            media.append(line[2:].split(" ", 1)[0])
            if len(media) > max_media:
                raise RequestRefused(TOO_MANY_MEDIA, f"an offer may carry at most {max_media} m-lines", 422)
    if "video" not in media:
        raise RequestRefused(NO_VIDEO, "the offer has no video track: add the camera's track before createOffer()", 422)
    candidates = sum(1 for line in lines if line.startswith(CANDIDATE))
    if candidates > MAX_CANDIDATES:
        raise RequestRefused(BAD_SDP, f"an offer may name at most {MAX_CANDIDATES} ICE candidates", 400)
    problem = text_problem(sdp) or sections_problem(lines)
    if problem:
        raise RequestRefused(BAD_SDP, f"this offer could never connect: {problem}", 400)
    robot_id = body.get("robot_id")
    if robot_id is not None and (not isinstance(robot_id, str) or len(robot_id) > MAX_ROBOT_ID_CHARS):
        raise RequestRefused(BAD_SDP, f"robot_id must be a string of at most {MAX_ROBOT_ID_CHARS} characters", 400)
    return Offer(sdp, robot_id, "application" in media)


def text_problem(sdp: str) -> str | None:
    """What in the SDP's characters no browser writes (SDP is ASCII but for free text: none is needed here)."""
    bad = next((c for c in sdp if not (" " <= c <= "~" or c in "\r\n\t")), None)
    return None if bad is None else f"it holds the character {bad!r}: an offer is printable ASCII"


def sections_problem(lines: list[str]) -> str | None:
    """What in the offer's m-sections aiortc would take and never connect: None when nothing."""
    sections: list[list[str]] = [[]]  # the session's lines, then each m-line's
    for line in lines:
        if line.startswith("m="):
            sections.append([])
        sections[-1].append(line)
    session = sections[0]
    for line in lines:
        if line.startswith("c=") and not _is_address_line(line[2:]):
            return f"{line[:60]!r} is no IN IP4 or IN IP6 address"
    for section in sections[1:]:
        problem = _media_problem(section, session)
        if problem:
            return f"{section[0][:40]!r}: {problem}"
    return None


def _media_problem(section: list[str], session: list[str]) -> str | None:
    fields = section[0][2:].split()
    if len(fields) < 4:
        return "an m-line is MEDIA PORT PROTO FORMAT..."
    port = fields[1].split("/")[0]
    if not port.isdigit() or int(port) > 65535:
        return f"port {port[:12]!r} is no UDP port"
    if port == "0":  # a rejected m-line: nothing to connect
        return None
    if "RTP" in fields[2] and not all(_payload_type(f) for f in fields[3:]):
        return f"its payload types must be numbers from 0 to {MAX_PAYLOAD_TYPE}"
    for line in section:
        if line.startswith(PAYLOAD_TYPED) and not _payload_type(line.split(":", 1)[1].split(" ", 1)[0]):
            return f"{line[:40]!r}: a payload type from 0 to {MAX_PAYLOAD_TYPE}"
    extmaps = [line[9:].split(" ", 1)[0].split("/")[0] for line in section if line.startswith("a=extmap:")]
    if len(extmaps) > MAX_EXTMAPS or not all(e.isdigit() and 1 <= int(e) <= 255 for e in extmaps):
        return f"at most {MAX_EXTMAPS} a=extmap lines, each with an id from 1 to 255"
    ufrag, password = _attribute(section, session, "ice-ufrag"), _attribute(section, session, "ice-pwd")
    if ufrag is None or password is None or not ICE_CHARS.match(ufrag) or not ICE_CHARS.match(password):
        return "no usable ICE credentials (a=ice-ufrag, a=ice-pwd): a non-trickle offer after ICE gathering"
    fingerprint = _attribute(section, session, "fingerprint")
    if fingerprint is None or not FINGERPRINT.match(fingerprint):
        return "no usable DTLS fingerprint (a=fingerprint:sha-256 AB:CD:...)"
    return None


def _attribute(section: list[str], session: list[str], name: str) -> str | None:
    """An attribute's value in the m-section, else at the session's level."""
    prefix = f"a={name}:"
    found = [line[len(prefix) :] for line in section + session if line.startswith(prefix)]
    return found[0].strip() if found else None


def _payload_type(text: str) -> bool:
    return text.isdigit() and len(text) <= 3 and int(text) <= MAX_PAYLOAD_TYPE


def _is_address_line(value: str) -> bool:
    """`IN IP4 ADDRESS` or `IN IP6 ADDRESS` (a multicast address may carry /TTL)."""
    fields = value.split()
    if len(fields) != 3 or fields[0] != "IN" or fields[1] not in ("IP4", "IP6"):
        return False
    try:
        address = ipaddress.ip_address(fields[2].split("/")[0])
    except ValueError:
        return False
    return address.version == (4 if fields[1] == "IP4" else 6)


def keep_candidates(sdp: str, reachable: frozenset[str]) -> tuple[str, int]:
    """The offer with only the ICE candidates whose address is in `reachable` (each written as `ipaddress` does); and
    how many were dropped (a name, `x.local` above all, is never resolved: dropped). The peer's own checks still
    reach the netapp: ICE learns its address from them (a peer-reflexive candidate)."""
    kept, dropped = [], 0
    for line in sdp.splitlines():
        if line.startswith(CANDIDATE):
            fields = line.split()
            if len(fields) < 5 or canonical_address(fields[4]) not in reachable:
                dropped += 1
                continue
        kept.append(line)
    return "\r\n".join(kept) + "\r\n", dropped


def canonical_address(text: str) -> str | None:
    """An IP address as `ipaddress` writes it (an IPv4-mapped IPv6 one as IPv4); None for anything else."""
    try:
        address = ipaddress.ip_address(text.split("%")[0])
    except ValueError:
        return None
    mapped = getattr(address, "ipv4_mapped", None)
    return str(mapped or address)
