from __future__ import annotations

from fastapi import APIRouter, Request
from pydantic import BaseModel, Field

from ..auth import TokenClaims
from ..dependencies import RobotDep, ServicesDep, check_login

router = APIRouter(prefix="/auth", tags=["auth"])


class Credentials(BaseModel):
    robot_id: str = Field(min_length=1, max_length=253)
    secret: str = Field(min_length=1, max_length=1024)


class Token(BaseModel):
    access_token: str
    token_type: str = "bearer"
    robot_id: str
    expires_at: float


def token_response(token: str, claims: TokenClaims) -> Token:
    return Token(access_token=token, robot_id=claims.robot_id, expires_at=claims.expires_at)


@router.post("/token")
def login(body: Credentials, services: ServicesDep, request: Request) -> Token:
    """Exchange a robot's id and secret for a bearer token (a sync route: scrypt runs in the threadpool)."""
    check_login(services, request, body.robot_id, body.secret)
    return token_response(*services.signer.issue(body.robot_id))


@router.post("/refresh")
def refresh(services: ServicesDep, robot_id: RobotDep) -> Token:
    """A fresh token for a still valid one, unless the robot has been removed from the robots file since (checked
    by `RobotDep` on every request)."""
    return token_response(*services.signer.issue(robot_id))
