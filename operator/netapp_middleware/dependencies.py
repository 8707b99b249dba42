"""Request dependencies: the shared services and the authenticated robot."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from netapp.http_errors import HTTPError

from .auth import AuthError, RobotRegistry
from .login_guard import Busy, TooManyFailures
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
        robot_id = services.signer.verify(credentials.credentials).robot_id
    except AuthError as exc:
        raise HTTPError(401, "unauthorized", str(exc), headers=CHALLENGE) from exc
    if not services.robots.known(robot_id):  # removed from the robots file: its tokens die with it
        message = f"robot {robot_id!r} is no longer registered: ask the operator"
        raise HTTPError(401, "unauthorized", message, headers=CHALLENGE)
    return robot_id


def check_login(
    services: Services, request: Request, robot_id: str, secret: str, registry: RobotRegistry | None = None
) -> None:
    """A robot's credentials (or, with `registry`, another list's, e.g. the dashboard's operators), checked under
    the login guard: 401, or 429 / 503 with Retry-After before hashing."""
    address = request.client.host if request.client else None
    try:
        services.logins.authenticate(registry or services.robots, robot_id, secret, address)
    except AuthError as exc:
        raise HTTPError(401, "unauthorized", str(exc)) from exc
    except TooManyFailures as exc:
        raise HTTPError(429, "too_many_requests", str(exc), headers={"Retry-After": str(exc.retry_after_s)}) from exc
    except Busy as exc:
        raise HTTPError(503, "unavailable", str(exc), headers={"Retry-After": str(exc.retry_after_s)}) from exc


ServicesDep = Annotated[Services, Depends(get_services)]
RobotDep = Annotated[str, Depends(current_robot)]
