"""Request dependencies: the shared services and the authenticated robot."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from netapp.http_errors import HTTPError

from .auth import AuthError
from .services import Services

_bearer = HTTPBearer(auto_error=False)
CHALLENGE = {"WWW-Authenticate": "Bearer"}


def get_services(request: Request) -> Services:
    return request.app.state.services


def current_robot(
    services: Annotated[Services, Depends(get_services)],
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> str:
    """The robot id of a valid bearer token; 401 otherwise."""
    if credentials is None:
        raise HTTPError(401, "unauthorized", "a bearer token is required: log in first", headers=CHALLENGE)
    try:
        return services.signer.verify(credentials.credentials).robot_id
    except AuthError as exc:
        raise HTTPError(401, "unauthorized", str(exc), headers=CHALLENGE) from exc


ServicesDep = Annotated[Services, Depends(get_services)]
RobotDep = Annotated[str, Depends(current_robot)]
