"""The paper's HTTP transport (register, send a JPEG, get or poll results, unregister), health and metrics.

Routes raise `HTTPError` (mapped to the one error body by `netapp.http_errors`); a frame's fate other than a result
(`FrameError`: rejected, superseded, session closed) maps to its status in `frame_error`.
"""

from __future__ import annotations

import asyncio
import logging
import re
import time
from dataclasses import asdict
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Header, Request
from fastapi.responses import JSONResponse, Response
from prometheus_client import CONTENT_TYPE_LATEST
from pydantic import BaseModel, Field
from starlette.requests import ClientDisconnect

from netapp.http_errors import HTTPError
from netapp.protocol import DEADLINE_HEADER, DRAINING_REASON, ROBOT_LATENCY_HEADER, parse_deadline_ms
from netapp.sdk.state import StateError
from netapp.server import access
from netapp.server.errors import FrameError, FrameRejected, SessionsFull
from netapp.server.frames import jpeg_frame
from netapp.server.heartbeat import heartbeat_body
from netapp.server.sessions import Session
from netapp.server.state import ServerState

log = logging.getLogger(__name__)
router = APIRouter()
JPEG_TYPES = {"image/jpeg", "image/jpg"}
TRANSPORT = "http"


class RegisterRequest(BaseModel):
    robot_id: str | None = Field(default=None, max_length=256)
    args: dict[str, Any] = Field(default_factory=dict)


class RegisterResponse(BaseModel):
    session_id: str


class SessionStats(BaseModel):
    session_id: str
    transport: str
    robot_id: str | None
    received: int
    processed: int
    dropped: int
    deadline_dropped: int
    rejected: int
    queue_depth: int


class PolledResults(BaseModel):
    results: list[dict[str, Any]]  # result messages, or {"timestamp", "error", "reason"} for a frame that failed
    dropped: int
    results_overflowed: int


class Queued(BaseModel):
    timestamp: int
    queued: bool = True


class Capacity(BaseModel):
    id: str | None
    name: str | None
    currentRobotsCount: int  # noqa: N815 (5G-ERA's field names)
    optimalLimit: int | None  # noqa: N815
    hardLimit: int | None  # noqa: N815
    capacity_fps: float | None
    demand_fps: float
    optimal: int | None
    hard: int | None
    measured: bool


class Health(BaseModel):
    status: str


# The dependencies below are `async def` although none awaits: FastAPI runs a plain `def` dependency on its thread
# pool, two thread hand-offs per frame (docs/benchmarks.md#profile).


def server_state(request: Request) -> ServerState:
    return request.app.state.netapp


async def state_of(request: Request) -> ServerState:
    return server_state(request)


State = Annotated[ServerState, Depends(state_of)]


def draining_error(message: str) -> HTTPError:
    """503 `draining`: this replica is going away; the robot goes on through the Service after Retry-After."""
    return HTTPError(503, DRAINING_REASON, message, headers={"Retry-After": "1"})


def sessions_full_error(exc: SessionsFull) -> HTTPError:
    return HTTPError(503, "sessions_full", str(exc), headers={"Retry-After": str(exc.retry_after_s)}, limit=exc.limit)


async def authorized(state: State, authorization: Annotated[str | None, Header()] = None) -> None:
    check_token(state, authorization)


def check_token(state: ServerState, authorization: str | None) -> None:
    """401 unless the request carries this netapp's token (when it has one: netapp.server.access)."""
    if not access.allows(state.settings.token_sha256, access.bearer(authorization)):
        message = "this netapp needs a token: send Authorization: Bearer <token> (the middleware gives it with the URL)"
        raise HTTPError(401, "unauthorized", message, headers={"WWW-Authenticate": "Bearer"})


Authorized = Annotated[None, Depends(authorized)]


async def http_session(state: State, _: Authorized, x_session_id: Annotated[str | None, Header()] = None) -> Session:
    return find_session(state, x_session_id)


def find_session(state: ServerState, x_session_id: str | None) -> Session:
    """The HTTP session named by X-Session-Id (kept alive by each request); 404 when there is none.

    The id is a token signed by the replicas (`netapp.server.cluster`): one first seen here is opened here."""
    session = state.sessions.get(x_session_id)
    if session is None and x_session_id and not state.sessions.revoked(x_session_id):
        claims = state.cluster.open_session_token(x_session_id)
        if claims is not None:
            try:
                session_state = state.pipeline.keeper.open(claims.args)  # checked when the token was issued
                session = state.sessions.create(
                    TRANSPORT, claims.robot_id, claims.args, state=session_state, session_id=x_session_id
                )
            except SessionsFull as exc:
                raise sessions_full_error(exc) from exc
    if session is None or session.transport != TRANSPORT:
        raise HTTPError(
            404, "unknown_session", "unknown session: send X-Session-Id from POST /register", session_id=x_session_id
        )
    session.touch()
    return session


async def frame_session(
    state: State,
    authorization: Annotated[str | None, Header()] = None,
    x_session_id: Annotated[str | None, Header()] = None,
) -> Session:
    """`http_session` for a frame: a frame without the token or for no session is counted as rejected."""
    try:
        check_token(state, authorization)
        return find_session(state, x_session_id)
    except HTTPError as exc:
        state.pipeline.reject(None, TRANSPORT, exc.reason)
        raise


HTTPSession = Annotated[Session, Depends(http_session)]


def frame_error(exc: FrameError, timestamp: Any) -> HTTPError:
    """What became of a frame instead of a result, as an HTTP answer: its status, reason and message (and, for a
    503 such as `draining` or `not_ready`, when to try again)."""
    retry = {"Retry-After": "1"} if exc.status == 503 else None
    return HTTPError(exc.status, exc.reason, str(exc), headers=retry, timestamp=timestamp)


@router.post("/register", status_code=201)
async def register(request: Request, state: State, _: Authorized) -> RegisterResponse:
    settings = state.settings
    try:
        body = await read_limited(request, settings.max_register_bytes, settings.body_timeout_s, "/register body")
    except FrameRejected as exc:
        raise HTTPError(exc.status, exc.reason, str(exc)) from exc
    try:
        payload = RegisterRequest.model_validate_json(body) if body.strip() else RegisterRequest()
    except ValueError as exc:
        message = f"body must be JSON {{'robot_id': str, 'args': {{...}}}}: {exc}"
        raise HTTPError(422, "invalid_request", message) from exc
    if state.draining:
        raise draining_error("this replica is draining: register again through the Service")
    try:
        token = state.cluster.session_token(payload.robot_id, payload.args)
    except ValueError as exc:
        raise HTTPError(413, "args_too_large", f"{exc}: send large settings another way") from exc
    try:
        session_state = state.pipeline.keeper.open(payload.args)
    except ValueError as exc:
        raise HTTPError(422, "invalid_request", str(exc)) from exc
    try:
        session = state.sessions.create(
            TRANSPORT, robot_id=payload.robot_id, args=payload.args, state=session_state, session_id=token
        )
    except SessionsFull as exc:
        raise sessions_full_error(exc) from exc
    return RegisterResponse(session_id=session.id)


@router.post("/unregister")
async def unregister(state: State, session: HTTPSession) -> SessionStats:
    state.close_session(session, "the session was unregistered", revoke=True)
    return SessionStats(**state.stats(session))


async def read_limited(request: Request, limit: int, timeout_s: float, what: str = "frame") -> bytes:
    """The body, refusing more than `limit` bytes without reading it all into memory first (413), and a body
    that takes longer than `timeout_s` to arrive (408: a half-sent request must not hold memory forever). A client
    that goes away mid-upload is one log line, not a traceback."""
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and len(declared) < 20 and int(declared) > limit:
        raise FrameRejected("payload_too_large", f"{what} of {declared} bytes is over the {limit}-byte limit", 413)
    chunks, size = [], 0
    try:
        async with asyncio.timeout(timeout_s):
            async for chunk in request.stream():
                size += len(chunk)
                if size > limit:
                    raise FrameRejected("payload_too_large", f"{what} is over the {limit}-byte limit", 413)
                chunks.append(chunk)
    except TimeoutError:
        raise FrameRejected("body_timeout", f"the {what} did not arrive within {timeout_s:.0f} s", 408) from None
    except ClientDisconnect:
        client = f"{request.client.host}:{request.client.port}" if request.client else "a client"
        log.info("%s went away during its upload (%d bytes of %s received)", client, size, what)
        raise FrameRejected("client_disconnected", "the client went away during the upload", 400) from None
    return b"".join(chunks)


def stateful(session: Session) -> None:
    if session.state is None:
        raise HTTPError(409, "stateless", "this netapp's processor keeps no session state")


@router.get("/state", responses={200: {"description": "the session's state (JSON), what PUT /state takes"}})
async def get_state(state: State, session: HTTPSession) -> Response:
    """A stateful processor's session state (GET_STATE over HTTP)."""
    stateful(session)
    try:
        text = await state.pipeline.keeper.get(session.state)
    except StateError as exc:
        raise HTTPError(500, "bad_state", str(exc)) from exc
    return Response(text, media_type="application/json")


@router.put("/state", status_code=204)
async def put_state(request: Request, state: State, session: HTTPSession) -> Response:
    """Replace the session's state with one from GET /state (SET_STATE over HTTP); 422 says what is wrong."""
    stateful(session)
    keeper = state.pipeline.keeper
    try:
        body = await read_limited(request, keeper.max_state_bytes, state.settings.body_timeout_s, what="state")
    except FrameRejected as exc:
        raise HTTPError(exc.status, exc.reason, str(exc)) from exc
    try:
        await keeper.set(session.state, body)
    except StateError as exc:
        raise HTTPError(422, "bad_state", str(exc)) from exc
    return Response(status_code=204)


TIMESTAMP = re.compile(r"-?[0-9]{1,20}")  # ASCII digits only: int() would take '²' and fail past 4300 digits


def parse_timestamp(text: str | None) -> int:
    """The X-Timestamp header (nanoseconds; now if absent); FrameRejected (422) unless a plain integer."""
    if text is None:
        return time.time_ns()
    if not TIMESTAMP.fullmatch(text):
        shown = text if len(text) <= 40 else text[:40] + "..."
        raise FrameRejected("bad_timestamp", f"X-Timestamp must be an integer of up to 20 digits, got {shown!r}", 422)
    return int(text)


@router.post(
    "/send_image",
    status_code=202,
    response_model=Queued,
    responses={200: {"description": "with ?wait=true: the frame's result message"}},
)
async def send_image(
    request: Request,
    state: State,
    session: Annotated[Session, Depends(frame_session)],
    wait: bool = False,
    x_timestamp: Annotated[str | None, Header()] = None,
    x_deadline_ms: Annotated[str | None, Header(alias=DEADLINE_HEADER)] = None,
    x_robot_latency: Annotated[str | None, Header(alias=ROBOT_LATENCY_HEADER)] = None,
) -> Queued | JSONResponse:
    recv_ns = time.monotonic_ns()
    pipeline, settings = state.pipeline, state.settings
    seq = pipeline.admit(session, TRANSPORT)
    try:
        if state.draining and not wait:  # its result would be kept here, and here is going away
            raise FrameRejected(DRAINING_REASON, "this replica is draining: register again through the Service", 503)
        content_type = request.headers.get("content-type", "").split(";")[0].strip().lower()
        if content_type not in JPEG_TYPES:
            raise FrameRejected("wrong_content_type", f"Content-Type must be image/jpeg, got {content_type!r}", 415)
        timestamp = parse_timestamp(x_timestamp)
        try:
            deadline_ms = parse_deadline_ms(x_deadline_ms)
        except ValueError as exc:
            raise FrameRejected("bad_deadline", f"{DEADLINE_HEADER}: {exc}", 422) from exc
        if wait and (state.waiting >= settings.max_waiting or session.waiting >= settings.max_waiting_per_session):
            raise FrameRejected(
                "too_many_waiting",
                f"too many requests wait for their result (at most {settings.max_waiting_per_session} per session, "
                f"{settings.max_waiting} in all): wait for an answer before sending more, or poll /results",
                503,
            )
        data = await read_limited(request, settings.max_payload_bytes, settings.body_timeout_s)
        decode = jpeg_frame(data, settings.max_pixels)
        if x_robot_latency is not None:
            state.live.report(session, x_robot_latency)
        waiter = await pipeline.receive(
            session, TRANSPORT, seq, timestamp, decode, wait=wait, recv_ns=recv_ns, deadline_ms=deadline_ms
        )
    except FrameRejected as exc:
        pipeline.reject(session, TRANSPORT, exc.reason)
        error = frame_error(exc, x_timestamp if x_timestamp is None or len(x_timestamp) <= 40 else None)
        if exc.status == 503:
            error.headers = {"Retry-After": "1"}
        raise error from exc
    if waiter is None:
        return Queued(timestamp=timestamp)
    state.waiting += 1
    session.waiting += 1
    try:
        message = await asyncio.wait_for(waiter, settings.wait_timeout_s)
    except FrameError as exc:  # counted by the pipeline
        raise frame_error(exc, timestamp) from exc
    except asyncio.TimeoutError:
        raise HTTPError(504, "timeout", f"no result within {settings.wait_timeout_s} s", timestamp=timestamp) from None
    finally:
        state.waiting -= 1
        session.waiting -= 1
    return JSONResponse(message)


@router.get("/results")
async def results(session: HTTPSession) -> PolledResults:
    return PolledResults(
        results=session.drain_results(), dropped=session.dropped, results_overflowed=session.results_overflowed
    )


@router.get("/healthz")
@router.get("/v2/health/live")
async def live() -> Health:
    return Health(status="live")


NOT_READY = {503: {"description": "the model is loading or failed to load, or the replica is draining"}}


@router.get("/readyz", responses=NOT_READY)
@router.get("/v2/health/ready", responses=NOT_READY)
async def ready(state: State) -> Health:
    pipeline = state.pipeline
    if state.draining:
        raise draining_error("this replica is draining: it takes no new robots")
    if pipeline.ready.is_set():
        return Health(status="ready")
    if pipeline.load_error is not None:
        raise HTTPError(503, "load_failed", f"model failed to load: {pipeline.load_error}")
    raise HTTPError(503, "not_ready", "model loading")


@router.get("/v2")
async def server_metadata(request: Request) -> dict:
    """KServe v2 server metadata, plus the one model this netapp serves (so a robot can say what answered it)."""
    from netapp import __version__

    models = [server_state(request).processor.describe()]
    return {"name": "netapp-toolkit", "version": __version__, "extensions": [], "models": models}


@router.get("/v2/models/{name}")
async def model_metadata(state: State, name: str) -> dict[str, Any]:
    processor = state.processor
    if name != processor.name:
        raise HTTPError(404, "unknown_model", f"unknown model {name!r}; this netapp serves {processor.name!r}")
    return processor.describe()


@router.get("/v2/models/{name}/ready")
async def model_ready(state: State, name: str) -> Health:
    if name != state.processor.name:
        raise HTTPError(404, "unknown_model", f"unknown model {name!r}")
    return await ready(state)


@router.get("/capacity")
async def capacity(state: State) -> Capacity:
    """What this replica can serve, as measured: the 5G-ERA heartbeat's fields and the figures behind them."""
    return Capacity(**heartbeat_body(state), **asdict(state.capacity()))


@router.get("/metrics")
async def metrics(state: State) -> Response:
    return Response(state.metrics.render(), media_type=CONTENT_TYPE_LATEST)
