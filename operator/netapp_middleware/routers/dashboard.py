"""The dashboard: NetApps (phase, pool, URL, robots) and each robot's deployments, live, for people.

Operators log in with their own credentials (`--operators-file`, scrypt hashes as for robots) and get a session
cookie signed with the dashboard's own key: a robot's bearer token opens nothing here, nor a session anything of
the robots' API. Each NetApp links to its own live page (`URL/ui`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Cookie, Request, Response
from fastapi.responses import FileResponse
from pydantic import BaseModel, Field

from netapp.http_errors import HTTPError

from ..auth import AuthError
from ..dependencies import ServicesDep, check_login

PAGE = Path(__file__).resolve().parent.parent / "static" / "dashboard.html"
COOKIE = "netapp_dashboard"

router = APIRouter(prefix="/dashboard", include_in_schema=False)


class Login(BaseModel):
    operator: str = Field(min_length=1, max_length=256)
    secret: str = Field(min_length=1, max_length=1024)


@router.get("")
async def page() -> FileResponse:
    return FileResponse(PAGE, media_type="text/html")


@router.post("/login", status_code=204)
def login(body: Login, services: ServicesDep, request: Request, response: Response) -> None:
    try:  # under the same guard as robots' logins: bounded hashing, failures rate-limited
        check_login(services, request, body.operator, body.secret, registry=services.operators)
    except HTTPError as exc:
        if exc.status != 401:
            raise
        message = "unknown operator or wrong secret: operators are listed in --operators-file"
        raise HTTPError(401, "unauthorized", message) from exc
    token, claims = services.operator_signer.issue(body.operator)
    max_age = int(claims.expires_at - claims.issued_at)
    response.set_cookie(COOKIE, token, max_age=max_age, httponly=True, samesite="strict", path="/dashboard")


@router.post("/logout", status_code=204)
def logout(response: Response) -> None:
    response.delete_cookie(COOKIE, path="/dashboard")


@router.get("/api/state")
def state(services: ServicesDep, netapp_dashboard: Annotated[str | None, Cookie()] = None) -> dict[str, Any]:
    if not netapp_dashboard:
        raise HTTPError(401, "unauthorized", "log in at /dashboard first")
    try:
        claims = services.operator_signer.verify(netapp_dashboard)
    except AuthError as exc:
        raise HTTPError(401, "unauthorized", f"{exc}: log in at /dashboard again") from exc
    if not services.operators.known(claims.robot_id):
        raise HTTPError(401, "unauthorized", "this operator was removed from --operators-file")
    return {"operator": claims.robot_id, **services.registry.overview(), **services.switchover.following.standbys()}
