"""What the routes are given: the dataplane, the netapp's settings (and, for the metrics and rollout routes, the app's
services), the token check and the robot's session.

They are `async def` although none awaits: FastAPI runs a plain `def` dependency on its thread pool, two thread
hand-offs per frame (docs/benchmarks.md#profile).
"""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Header, Request

from netapp.http_errors import HTTPError
from netapp.protocol import UNAUTHORIZED_REASON
from netapp.server import access
from netapp.server.dataplane import DataPlane
from netapp.server.errors import ServingError
from netapp.server.http.errors import http_error
from netapp.server.services import NetAppServices
from netapp.server.sessions import TOKEN_TRANSPORT, Session
from netapp.server.settings import Settings

TRANSPORT = TOKEN_TRANSPORT  # the `transport` label of HTTP frames: HTTP sessions are token sessions


async def dataplane_of(request: Request) -> DataPlane:
    return request.app.state.dataplane


async def services_of(request: Request) -> NetAppServices:
    return request.app.state.netapp


async def settings_of(request: Request) -> Settings:
    return request.app.state.settings


Plane = Annotated[DataPlane, Depends(dataplane_of)]
Services = Annotated[NetAppServices, Depends(services_of)]
Tunables = Annotated[Settings, Depends(settings_of)]  # the netapp's settings (what a request is bounded by)


def check_token(settings: Settings, authorization: str | None) -> int:
    """401 unless the request carries this netapp's token (when it has one: netapp.server.access); the highest
    priority class the token lets its robot claim."""
    granted = access.granted_class(settings, access.bearer(authorization))
    if granted is None:
        message = "this netapp needs a token: send Authorization: Bearer <token> (the middleware gives it with the URL)"
        raise HTTPError(401, UNAUTHORIZED_REASON, message, headers={"WWW-Authenticate": "Bearer"})
    return granted


async def authorized(settings: Tunables, authorization: Annotated[str | None, Header()] = None) -> int:
    return check_token(settings, authorization)


Authorized = Annotated[int, Depends(authorized)]  # the highest priority class the request's token grants


async def http_session(plane: Plane, _: Authorized, x_session_id: Annotated[str | None, Header()] = None) -> Session:
    """The session named by X-Session-Id (`DataPlane.token_session`); 404 when there is none."""
    return await live_token_session(plane, x_session_id)


async def live_token_session(plane: DataPlane, token: str | None) -> Session:
    """`DataPlane.token_session`, refused (404) once its owner says the robot unregistered there
    (`netapp.server.cluster.revocation`)."""
    session = plane.token_session(token)
    if await plane.unregistered_elsewhere(session):
        plane.close_session(session, "the session was unregistered", revoke=True)
        return plane.token_session(token)  # now refused: 404 unknown_session
    return session


HTTPSession = Annotated[Session, Depends(http_session)]


async def frame_session(
    plane: Plane,
    settings: Tunables,
    authorization: Annotated[str | None, Header()] = None,
    x_session_id: Annotated[str | None, Header()] = None,
) -> Session:
    """`http_session` for a frame: a frame without the token or for no session is counted as rejected."""
    try:
        check_token(settings, authorization)
        return await live_token_session(plane, x_session_id)
    except ServingError as exc:
        plane.refuse(TRANSPORT, exc.reason)
        raise http_error(exc) from exc
    except HTTPError as exc:
        plane.refuse(TRANSPORT, exc.reason)
        raise


FrameSession = Annotated[Session, Depends(frame_session)]
