"""The 5G-ERA state commands over HTTP, for a stateful processor: GET /state (GET_STATE), PUT /state (SET_STATE)."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import Response

from netapp.server.http.body import read_limited
from netapp.server.http.dependencies import HTTPSession, Plane, Tunables

router = APIRouter()


@router.get("/state", responses={200: {"description": "the session's state (JSON), what PUT /state takes"}})
async def get_state(plane: Plane, session: HTTPSession) -> Response:
    """A stateful processor's session state (GET_STATE over HTTP)."""
    return Response(await plane.get_state(session), media_type="application/json")


@router.put("/state", status_code=204)
async def put_state(request: Request, plane: Plane, settings: Tunables, session: HTTPSession) -> Response:
    """Replace the session's state with one from GET /state (SET_STATE over HTTP); 422 says what is wrong."""
    limit = plane.max_state_bytes(session)
    body = await read_limited(request, limit, settings.body_timeout_s, what="state")
    await plane.set_state(session, body)
    return Response(status_code=204)
