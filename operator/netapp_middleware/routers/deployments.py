from __future__ import annotations

import time
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel, Field, ValidationError

from netapp.http_errors import HTTPError
from netapp.tracecontext import TRACEPARENT, TRACESTATE

from ..catalogue import PLACEMENT_PATTERN
from ..dependencies import RobotDep, ServicesDep
from ..deployments import NotFound, QuotaExceeded, Unrunnable
from ..switchover import TooFrequent
from ..switchover.ahead import RouteRefused
from ..switchover.following import TooSoon

router = APIRouter(prefix="/deployments", tags=["deployments"])

MAX_HEDGE = 4  # placements of one hedged deployment
MAX_REPORT_BYTES = 1024  # a latency report is four numbers
MAX_ROUTE_BYTES = 4096  # a route of at most AheadPolicy.max_waypoints (pool, eta) pairs


class DeploymentRequest(BaseModel):
    app: str = Field(min_length=1, max_length=253)
    placement: str | None = Field(
        default=None, pattern=PLACEMENT_PATTERN, description="edge, cloud, auto, or a node pool name"
    )
    reuse: bool = Field(
        default=True, description="share a NetApp with other robots asking for the same app and placement"
    )
    hedge: list[Annotated[str, Field(pattern=PLACEMENT_PATTERN)]] | None = Field(
        default=None,
        min_length=2,
        max_length=MAX_HEDGE,
        description="deploy on each of these placements at once (the first is the primary) and return every URL",
    )


class LatencyReport(BaseModel):
    """What the robot's client measured on its netapp over the last `window_s` seconds."""

    p95_ms: float | None = Field(ge=0, le=3_600_000, description="null when no result came back in the window")
    deadline_ms: float = Field(gt=0, le=3_600_000, description="the robot's latency budget")
    missed: int = Field(default=0, ge=0, le=1_000_000, description="frames that missed the deadline or were lost")
    window_s: float = Field(default=1.0, gt=0, le=3600)
    url: str | None = Field(default=None, max_length=2048, description="the netapp the robot measured")


class Waypoint(BaseModel):
    pool: str = Field(pattern=PLACEMENT_PATTERN, description="a placement the middleware serves")
    eta: float = Field(description="when the robot gets there, Unix seconds")


class Route(BaseModel):
    """Where the robot heads: the next pool and when, or several; empty: no route."""

    route: list[Waypoint] = Field(max_length=256)  # the policy's own bound, lower, says why in one line


@router.post("", status_code=202)
async def create(
    body: DeploymentRequest, request: Request, services: ServicesDep, robot_id: RobotDep
) -> dict[str, Any]:
    started = time.monotonic_ns()
    app = (await run_in_threadpool(services.catalogue)).get(body.app)
    if app is None:
        raise HTTPError(404, "not_found", f"no app {body.app!r} in the catalogue: GET /apps lists them")
    if body.hedge and body.placement is not None:
        raise HTTPError(422, "invalid_request", "give either placement or hedge (its first placement is the primary)")
    if body.hedge and len(set(body.hedge)) < 2:
        raise HTTPError(422, "invalid_request", "hedge needs two different placements, e.g. [edge, cloud]")
    try:
        # the token it is given for its netapps is its class's (netapp_middleware.priorities)
        meta = {"priority": await run_in_threadpool(services.robots.priority, robot_id)}
        traces, headers = services.traces, request.headers
        trace = traces.begin(headers.get(TRACEPARENT), headers.get(TRACESTATE), started) if traces else None
        deployment = services.registry.create(
            robot_id, app, body.placement, body.reuse, meta, hedge=body.hedge, trace=trace
        )
    except QuotaExceeded as exc:
        raise HTTPError(429, "too_many_requests", str(exc)) from exc
    except Unrunnable as exc:
        raise HTTPError(422, "unrunnable_spec", str(exc)) from exc
    return handed_out(services, deployment, deployment.view(), started)


def handed_out(services: Any, deployment: Any, view: dict[str, Any], started_ns: int) -> dict[str, Any]:
    """`view` as it goes to the robot; a sampled deployment's trace ends with the first that carries its URL."""
    if services.traces is not None:
        services.traces.handed_out(deployment, view, started_ns)
    return view


@router.get("")
async def list_deployments(services: ServicesDep, robot_id: RobotDep) -> dict[str, Any]:
    return {"deployments": [d.view() for d in services.registry.list(robot_id)]}


@router.get("/{deployment_id}")
async def get(
    deployment_id: str,
    services: ServicesDep,
    robot_id: RobotDep,
    wait: float = Query(
        0.0, ge=0.0, description="long-poll: return as soon as the deployment changes, or after this many seconds"
    ),
    since: int | None = Query(None, description="the `version` the robot last saw (default: the current one)"),
) -> dict[str, Any]:
    started = time.monotonic_ns()
    try:
        if wait > 0:
            deployment = await services.registry.wait(robot_id, deployment_id, since, min(wait, services.max_wait_s))
        else:
            deployment = services.registry.get(robot_id, deployment_id)
    except NotFound as exc:
        raise HTTPError(404, "not_found", "no such deployment") from exc
    view = {**deployment.view(), "route": services.switchover.following.route_of(deployment.id)}
    return handed_out(services, deployment, view, started)


@router.delete("/{deployment_id}", status_code=204)
async def delete(deployment_id: str, services: ServicesDep, robot_id: RobotDep) -> Response:
    try:
        await services.registry.delete(robot_id, deployment_id)
    except NotFound as exc:
        raise HTTPError(404, "not_found", "no such deployment") from exc
    return Response(status_code=204)


@router.post("/{deployment_id}/report")
async def report(deployment_id: str, request: Request, services: ServicesDep, robot_id: RobotDep) -> dict[str, Any]:
    """The robot's latency on its netapp; the middleware moves it to a better placement when it stays over budget
    (see netapp_middleware.switchover.decision). Answers the decision."""
    body = await read_bounded(request, MAX_REPORT_BYTES)
    try:
        measured = LatencyReport.model_validate_json(body)
    except ValidationError as exc:
        raise HTTPError(
            422, "invalid_request", f"a latency report is {{p95_ms, deadline_ms, missed, window_s}}: {exc}"
        ) from exc
    try:
        deployment = services.registry.get(robot_id, deployment_id)
    except NotFound as exc:
        raise HTTPError(404, "not_found", "no such deployment") from exc
    try:
        decision = services.switchover.report(
            deployment, measured.p95_ms, measured.deadline_ms, measured.missed, measured.window_s, measured.url
        )
    except TooFrequent as exc:
        raise HTTPError(429, "too_many_requests", f"{exc}: report less often") from exc
    return {"reason": decision.reason, "message": decision.message, "moveTo": decision.move_to}


@router.put("/{deployment_id}/route")
async def route(deployment_id: str, request: Request, services: ServicesDep, robot_id: RobotDep) -> dict[str, Any]:
    """Where the robot heads: the middleware readies each pool before its eta, moves the robot there on time and
    releases what it left behind (see netapp_middleware.switchover.ahead). Answers the route it follows."""
    body = await read_bounded(request, MAX_ROUTE_BYTES)
    try:
        given = Route.model_validate_json(body)
    except ValidationError as exc:
        raise HTTPError(422, "invalid_request", f"a route is {{route: [{{pool, eta}}, ...]}}: {exc}") from exc
    try:
        deployment = services.registry.get(robot_id, deployment_id)
    except NotFound as exc:
        raise HTTPError(404, "not_found", "no such deployment") from exc
    try:
        services.switchover.following.set_route(deployment, [(w.pool, w.eta) for w in given.route])
    except RouteRefused as exc:
        raise HTTPError(422, "invalid_route", str(exc)) from exc
    except TooSoon as exc:
        raise HTTPError(429, "too_many_requests", f"{exc}: send a route when it changes") from exc
    return {"id": deployment.id, "route": services.switchover.following.route_of(deployment.id)}


async def read_bounded(request: Request, limit: int) -> bytes:
    """The request body, refused with 413 past `limit` bytes before more of it is read."""
    declared = request.headers.get("content-length")
    if declared is not None and (not declared.isdigit() or int(declared) > limit):
        raise HTTPError(413, "payload_too_large", f"a body of at most {limit} bytes")
    body = bytearray()
    async for chunk in request.stream():
        body += chunk
        if len(body) > limit:
            raise HTTPError(413, "payload_too_large", f"a body of at most {limit} bytes")
    return bytes(body)
