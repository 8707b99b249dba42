"""Request dependencies: the shared services and the authenticated robot."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, HTTPException, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from .app import Services
from .auth import AuthError
from .login_guard import Busy, TooManyFailures

_bearer = HTTPBearer(auto_error=False)


def get_services(request: Request) -> Services:
    return request.app.state.services


def current_robot(
    services: Annotated[Services, Depends(get_services)],
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> str:
    """The robot id of a valid bearer token; 401 otherwise."""
    if credentials is None:
        raise HTTPException(401, "a bearer token is required", headers={"WWW-Authenticate": "Bearer"})
    try:
        robot_id = services.signer.verify(credentials.credentials).robot_id
    except AuthError as exc:
        raise HTTPException(401, str(exc), headers={"WWW-Authenticate": "Bearer"}) from exc
    if not services.robots.known(robot_id):  # removed from the robots file: its tokens die with it
        raise HTTPException(
            401, f"robot {robot_id!r} is no longer registered: ask the operator", headers={"WWW-Authenticate": "Bearer"}
        )
    return robot_id


def check_login(services: Services, request: Request, robot_id: str, secret: str) -> None:
    """A robot's credentials, checked under the login guard: 401, or 429 / 503 with Retry-After before hashing."""
    address = request.client.host if request.client else None
    try:
        services.logins.authenticate(services.robots, robot_id, secret, address)
    except AuthError as exc:
        raise HTTPException(401, str(exc)) from exc
    except (TooManyFailures, Busy) as exc:
        status = 429 if isinstance(exc, TooManyFailures) else 503
        raise HTTPException(status, str(exc), headers={"Retry-After": str(exc.retry_after_s)}) from exc


ServicesDep = Annotated[Services, Depends(get_services)]
RobotDep = Annotated[str, Depends(current_robot)]
