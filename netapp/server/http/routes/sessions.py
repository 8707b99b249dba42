"""Opening and closing an HTTP session: POST /register (a signed token good on any replica), POST /unregister."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Request

from netapp.http_errors import HTTPError
from netapp.server.cluster.revocation import REVOKED_PATH
from netapp.server.errors import ServingError
from netapp.server.http.body import read_limited
from netapp.server.http.dependencies import Authorized, HTTPSession, Plane
from netapp.server.http.schemas import RegisterRequest, RegisterResponse, SessionStats
from netapp.server.rtp.hub import PollingSink
from netapp.server.rtp.request import RTP_FIELD

router = APIRouter()


@router.post("/register", status_code=201)
async def register(request: Request, plane: Plane, granted: Authorized) -> RegisterResponse:
    settings = plane.settings
    body = await read_limited(request, settings.max_register_bytes, settings.body_timeout_s, "/register body")
    try:
        payload = RegisterRequest.model_validate_json(body) if body.strip() else RegisterRequest()
    except ValueError as exc:
        message = f"body must be JSON {{'robot_id': str, 'args': {{...}}}}: {exc}"
        raise HTTPError(422, "invalid_request", message) from exc
    rtp = request.app.state.rtp if RTP_FIELD in payload.args else None
    asked = rtp.check(payload.args[RTP_FIELD]) if rtp is not None else None  # before any session opens
    session = plane.register(payload.robot_id, payload.args, granted)
    answer = None
    if rtp is not None and asked is not None:
        try:
            answer = await rtp.open(session, PollingSink(plane), asked, request.scope.get("server", ("127.0.0.1",))[0])
        except ServingError as exc:
            plane.close_session(session, str(exc), revoke=True)
            raise
    return RegisterResponse(session_id=session.id, rtp=answer, **plane.session_info())


@router.get(REVOKED_PATH, include_in_schema=False)
async def revoked(plane: Plane, x_session_id: Annotated[str | None, Header()] = None) -> dict[str, bool]:
    """For the other replicas: whether this token was unregistered here (`netapp.server.cluster.revocation`)."""
    return {"revoked": bool(x_session_id) and plane.services.sessions.revoked(x_session_id)}


@router.post("/unregister")
async def unregister(plane: Plane, session: HTTPSession) -> SessionStats:
    plane.close_session(session, "the session was unregistered", revoke=True)
    return SessionStats(**plane.stats(session))
