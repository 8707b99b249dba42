"""WebRTC signalling (the `webrtc` extra; docs/cameras.md#webrtc): `POST /webrtc/offer`, an SDP offer in, the
answer out (non-trickle ICE: every candidate is in the answer). The robot's token, as for any robot."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request

from netapp import wire_json
from netapp.server.errors import FrameRejected
from netapp.server.http.body import read_limited
from netapp.server.http.dependencies import Authorized
from netapp.server.webrtc import offer as offers
from netapp.server.webrtc.peers import WebRtcPeers

router = APIRouter()
BODY_TIMEOUT_S = 10.0
JSON_OVERHEAD_BYTES = 4096  # the offer's JSON around its SDP (escaped newlines, robot_id)


@router.post("/webrtc/offer")
async def webrtc_offer(request: Request, _: Authorized) -> dict[str, Any]:
    """`{"type": "offer", "sdp": ..., "robot_id": ...}` -> `{"type": "answer", "sdp": ..., "session": ...}`; the
    results come back on the peer's data channel."""
    peers: WebRtcPeers = request.app.state.webrtc
    if not peers.available:
        return await peers.answer(None, "")  # refused, saying which extra to install
    limit = peers.settings.webrtc_max_sdp_bytes + JSON_OVERHEAD_BYTES
    try:
        raw = await read_limited(request, limit, BODY_TIMEOUT_S, "offer")
    except FrameRejected as exc:
        reason = offers.SDP_TOO_LARGE if exc.status == 413 else offers.BAD_SDP
        peers.metrics.refused.labels(reason=reason).inc()
        raise
    try:
        body = wire_json.loads(raw)
    except ValueError:
        body = None  # refused by the check, counted
    return await peers.answer(body, request.client.host if request.client else "")
