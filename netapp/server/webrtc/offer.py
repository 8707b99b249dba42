"""An SDP offer, checked before aiortc parses it (pure): its size, its text, its m-lines. Every byte of it is the
caller's, so each bound is checked before the work it bounds, and each refusal has a reason the metrics count.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from netapp.server.errors import RequestRefused

MAX_SDP_BYTES = 16 * 1024  # a browser's offer of one video and one data channel is 3 to 6 KB (Chromium: ~4.5 KB)
MAX_MEDIA = 4  # m-lines: the page and `netapp stream` offer two (video, application)
MAX_LINE_CHARS = 1024  # a line longer than this is no SDP a browser writes
MAX_ROBOT_ID_CHARS = 128

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
    robot_id = body.get("robot_id")
    if robot_id is not None and (not isinstance(robot_id, str) or len(robot_id) > MAX_ROBOT_ID_CHARS):
        raise RequestRefused(BAD_SDP, f"robot_id must be a string of at most {MAX_ROBOT_ID_CHARS} characters", 400)
    return Offer(sdp, robot_id, "application" in media)
