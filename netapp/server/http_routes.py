"""The paper's HTTP transport (register, send a JPEG, get or poll results, unregister), health and metrics.

Routes raise `HTTPError` (mapped to the one error body by `netapp.http_errors`); a frame's fate other than a result
(`FrameError`: rejected, superseded, session closed) maps to its status in `frame_error`.
"""

from __future__ import annotations

import asyncio
import time
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Header, Request
from fastapi.responses import JSONResponse, Response
from prometheus_client import CONTENT_TYPE_LATEST
from pydantic import BaseModel, Field

from netapp.http_errors import HTTPError
from netapp.server.errors import FrameError, FrameRejected
from netapp.server.frames import jpeg_frame
from netapp.server.sessions import Session
from netapp.server.state import ServerState

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
    rejected: int
    queue_depth: int


class PolledResults(BaseModel):
    results: list[dict[str, Any]]  # result messages, or {"timestamp", "error", "reason"} for a frame that failed
    dropped: int
    results_overflowed: int


class Queued(BaseModel):
    timestamp: int
    queued: bool = True


class Health(BaseModel):
    status: str


def state_of(request: Request) -> ServerState:
    return request.app.state.netapp


State = Annotated[ServerState, Depends(state_of)]


def http_session(state: State, x_session_id: Annotated[str | None, Header()] = None) -> Session:
    """The HTTP session named by X-Session-Id (kept alive by each request); 404 when there is none."""
    session = state.sessions.get(x_session_id)
    if session is None or session.transport != TRANSPORT:
        raise HTTPError(
            404, "unknown_session", "unknown session: send X-Session-Id from POST /register", session_id=x_session_id
        )
    session.touch()
    return session


def frame_session(state: State, x_session_id: Annotated[str | None, Header()] = None) -> Session:
    """`http_session` for a frame: a frame for no session is counted as rejected."""
    try:
        return http_session(state, x_session_id)
    except HTTPError as exc:
        state.pipeline.reject(None, TRANSPORT, exc.reason)
        raise


HTTPSession = Annotated[Session, Depends(http_session)]


def frame_error(exc: FrameError, timestamp: Any) -> HTTPError:
    """What became of a frame instead of a result, as an HTTP answer: its status, reason and message."""
    return HTTPError(exc.status, exc.reason, str(exc), timestamp=timestamp)


@router.post("/register", status_code=201)
async def register(request: Request, state: State) -> RegisterResponse:
    body = await request.body()
    try:
        payload = RegisterRequest.model_validate_json(body) if body.strip() else RegisterRequest()
    except ValueError as exc:
        message = f"body must be JSON {{'robot_id': str, 'args': {{...}}}}: {exc}"
        raise HTTPError(422, "invalid_request", message) from exc
    session = state.sessions.create(TRANSPORT, robot_id=payload.robot_id, args=payload.args)
    return RegisterResponse(session_id=session.id)


@router.post("/unregister")
async def unregister(state: State, session: HTTPSession) -> SessionStats:
    state.close_session(session, "the session was unregistered")
    return SessionStats(**state.stats(session))


async def read_limited(request: Request, limit: int) -> bytes:
    """The body, refusing more than `limit` bytes without reading it all into memory first."""
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and int(declared) > limit:
        raise FrameRejected("payload_too_large", f"frame of {declared} bytes is over the {limit}-byte limit", 413)
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            raise FrameRejected("payload_too_large", f"frame is over the {limit}-byte limit", 413)
        chunks.append(chunk)
    return b"".join(chunks)


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
    x_robot_latency: Annotated[str | None, Header()] = None,
) -> Queued | JSONResponse:
    recv_ns = time.monotonic_ns()
    pipeline = state.pipeline
    seq = pipeline.admit(session, TRANSPORT)
    try:
        content_type = request.headers.get("content-type", "").split(";")[0].strip().lower()
        if content_type not in JPEG_TYPES:
            raise FrameRejected("wrong_content_type", f"Content-Type must be image/jpeg, got {content_type!r}", 415)
        if x_timestamp is not None and not x_timestamp.lstrip("-").isdigit():
            raise FrameRejected("bad_timestamp", f"X-Timestamp must be an integer, got {x_timestamp!r}", 422)
        timestamp = int(x_timestamp) if x_timestamp is not None else time.time_ns()
        data = await read_limited(request, state.settings.max_payload_bytes)
        decode = jpeg_frame(data)
        if x_robot_latency is not None:
            state.live.report(session, x_robot_latency)
        waiter = await pipeline.receive(session, TRANSPORT, seq, timestamp, decode, wait=wait, recv_ns=recv_ns)
    except FrameRejected as exc:
        pipeline.reject(session, TRANSPORT, exc.reason)
        raise frame_error(exc, x_timestamp) from exc
    if waiter is None:
        return Queued(timestamp=timestamp)
    try:
        message = await asyncio.wait_for(waiter, state.settings.wait_timeout_s)
    except FrameError as exc:  # counted by the pipeline
        raise frame_error(exc, timestamp) from exc
    except asyncio.TimeoutError:
        raise HTTPError(
            504, "timeout", f"no result within {state.settings.wait_timeout_s} s", timestamp=timestamp
        ) from None
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


@router.get("/readyz", responses={503: {"description": "the model is loading, or failed to load"}})
@router.get("/v2/health/ready", responses={503: {"description": "the model is loading, or failed to load"}})
async def ready(state: State) -> Health:
    pipeline = state.pipeline
    if pipeline.ready.is_set():
        return Health(status="ready")
    if pipeline.load_error is not None:
        raise HTTPError(503, "load_failed", f"model failed to load: {pipeline.load_error}")
    raise HTTPError(503, "not_ready", "model loading")


@router.get("/v2")
async def server_metadata(request: Request) -> dict:
    """KServe v2 server metadata, plus the one model this netapp serves (so a robot can say what answered it)."""
    from netapp import __version__

    models = [state_of(request).processor.describe()]
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


@router.get("/metrics")
async def metrics(state: State) -> Response:
    return Response(state.metrics.render(), media_type=CONTENT_TYPE_LATEST)
