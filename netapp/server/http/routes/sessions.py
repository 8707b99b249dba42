"""Opening and closing an HTTP session: POST /register (a signed token good on any replica), POST /unregister."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Request

from netapp.http_errors import HTTPError
from netapp.server.cluster.revocation import REVOKED_PATH
from netapp.server.commands import Commands
from netapp.server.http.body import read_limited
from netapp.server.http.dependencies import Authorized, HTTPSession, Plane, Tunables
from netapp.server.http.schemas import RegisterRequest, RegisterResponse, SessionStats

router = APIRouter()


@router.post("/register", status_code=201)
async def register(request: Request, plane: Plane, settings: Tunables, granted: Authorized) -> RegisterResponse:
    """A session as INIT opens one, RTP included (`Commands.register`, the one dispatch)."""
    body = await read_limited(request, settings.max_register_bytes, settings.body_timeout_s, "/register body")
    try:
        payload = RegisterRequest.model_validate_json(body) if body.strip() else RegisterRequest()
    except ValueError as exc:
        message = f"body must be JSON {{'robot_id': str, 'args': {{...}}}}: {exc}"
        raise HTTPError(422, "invalid_request", message) from exc
    commands: Commands = request.app.state.commands
    host = request.scope.get("server", ("127.0.0.1",))[0]  # where its RTP goes, if it asks for RTP
    registered = await commands.register(payload.robot_id, payload.args, granted, host)
    return RegisterResponse(session_id=registered.session.id, rtp=registered.rtp, **plane.session_info())


@router.get(REVOKED_PATH, include_in_schema=False)
async def revoked(plane: Plane, x_session_id: Annotated[str | None, Header()] = None) -> dict[str, bool]:
    """For the other replicas: whether this token was unregistered here (`netapp.server.cluster.revocation`)."""
    return {"revoked": plane.revoked(x_session_id)}


@router.post("/unregister")
async def unregister(plane: Plane, session: HTTPSession) -> SessionStats:
    plane.close_session(session, "the session was unregistered", revoke=True)
    return SessionStats(**plane.stats(session))
