"""The 5G-ERA middleware endpoints that era-5g-client's NetAppClient calls, mapped onto deployments.

Errors carry the one error body (`error`, `reason`) plus 5G-ERA's own fields, `errors` in a failed login and
`statusCode` and `message` in a failed plan request, so era-5g-client reads them as it would from 5G-ERA.
"""

from __future__ import annotations

import datetime
from typing import Any

from fastapi import APIRouter, Request, Response
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel, ConfigDict, Field

from netapp.http_errors import HTTPError

from ..action_plan import plan_view
from ..catalogue import PLACEMENT_PATTERN
from ..dependencies import RobotDep, ServicesDep, check_login
from ..deployments import NotFound, QuotaExceeded, Unrunnable
from ..switchover.ahead import RouteRefused

router = APIRouter(tags=["5G-ERA"])


def _plan_refused(status: int, reason: str, message: str) -> HTTPError:
    """A refused plan: the one error body plus what era-5g-client raises with, `statusCode` (400 in 5G-ERA,
    whatever the HTTP status) and `message`."""
    return HTTPError(status, reason, message, statusCode=400, message=message)


class LoginRequest(BaseModel):
    model_config = ConfigDict(extra="allow")
    Id: str
    Password: str


class EraWaypoint(BaseModel):
    """Ours, beside 5G-ERA's keys: where the robot heads (`Location` as in 5G-ERA's plans) and when (`Eta`,
    Unix seconds or ISO 8601)."""

    Location: str = Field(pattern=PLACEMENT_PATTERN)
    Eta: float | datetime.datetime

    def unix(self) -> float:
        return self.Eta.timestamp() if isinstance(self.Eta, datetime.datetime) else float(self.Eta)


class PlanRequest(BaseModel):
    model_config = ConfigDict(extra="allow")
    TaskId: str
    DisableResourceReuse: bool = False
    RobotId: str | None = None
    Route: list[EraWaypoint] | None = Field(default=None, max_length=256)  # an unmodified client sends none


@router.post("/Login")
def login(body: LoginRequest, services: ServicesDep, request: Request) -> Any:
    try:
        check_login(services, request, body.Id, body.Password)
    except HTTPError as exc:  # with 5G-ERA's `errors`
        raise HTTPError(exc.status, exc.reason, str(exc), headers=exc.headers, errors=[str(exc)]) from exc
    token, claims = services.signer.issue(body.Id, ttl_s=services.era_token_ttl_s)
    expires = datetime.datetime.fromtimestamp(claims.expires_at, tz=datetime.timezone.utc).isoformat()
    return {"token": token, "expirationDate": expires, "id": body.Id}


@router.post("/Task/Plan")
async def plan(body: PlanRequest, services: ServicesDep, robot_id: RobotDep) -> Any:
    app = (await run_in_threadpool(services.catalogue)).by_task_id(body.TaskId)
    if app is None:
        raise _plan_refused(400, "bad_request", f"no app with task id {body.TaskId} in the catalogue")
    route = [(w.Location, w.unix()) for w in body.Route or ()]
    following = services.switchover.following
    try:
        following.check(route)  # before anything is deployed: a bad route refuses the plan
        deployment = services.registry.create(
            robot_id, app, None, not body.DisableResourceReuse, meta={"taskId": body.TaskId, "robotId": body.RobotId}
        )
    except RouteRefused as exc:
        raise _plan_refused(400, "invalid_route", f"Route: {exc}") from exc
    except QuotaExceeded as exc:
        raise _plan_refused(429, "too_many_requests", str(exc)) from exc
    except Unrunnable as exc:
        raise _plan_refused(422, "unrunnable_spec", str(exc)) from exc
    if route:
        following.set_route(deployment, route)
    return {**plan_view(deployment), "ActionPlanId": deployment.id, "Route": following.route_of(deployment.id)}


@router.get("/orchestrate/orchestrate/plan/{plan_id}")
async def get_plan(plan_id: str, services: ServicesDep, robot_id: RobotDep) -> dict[str, Any]:
    try:
        return plan_view(services.registry.get(robot_id, plan_id))
    except NotFound as exc:
        raise HTTPError(404, "not_found", "no such action plan") from exc


@router.delete("/orchestrate/orchestrate/plan/{plan_id}")
async def delete_plan(plan_id: str, services: ServicesDep, robot_id: RobotDep) -> Response:
    try:
        await services.registry.delete(robot_id, plan_id)
    except NotFound as exc:
        raise HTTPError(404, "not_found", "no such action plan") from exc
    return Response(status_code=200)
