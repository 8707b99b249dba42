"""The paper's HTTP transport (register, send a JPEG, get or poll results, unregister), health and metrics."""

from __future__ import annotations

import asyncio
import time
from typing import Any

from fastapi import APIRouter, Header, Request
from fastapi.responses import JSONResponse, Response
from prometheus_client import CONTENT_TYPE_LATEST
from pydantic import BaseModel, Field

from netapp.server.errors import FrameDropped, FrameRejected, SessionClosed
from netapp.server.frames import jpeg_frame
from netapp.server.sessions import Session
from netapp.server.state import ServerState

router = APIRouter()
JPEG_TYPES = {"image/jpeg", "image/jpg"}


class RegisterRequest(BaseModel):
    robot_id: str | None = Field(default=None, max_length=256)
    args: dict[str, Any] = Field(default_factory=dict)


def error(status: int, message: str, **extra: Any) -> JSONResponse:
    return JSONResponse({"error": message, **extra}, status_code=status)


def state_of(request: Request) -> ServerState:
    return request.app.state.netapp


def session_of(state: ServerState, session_id: str | None) -> Session | JSONResponse:
    session = state.sessions.get(session_id)
    if session is None or session.transport != "http":
        return error(404, "unknown session: send X-Session-Id from POST /register", session_id=session_id)
    session.last_seen = time.monotonic()
    return session


@router.post("/register")
async def register(request: Request) -> Response:
    state = state_of(request)
    body = await request.body()
    try:
        payload = RegisterRequest.model_validate_json(body) if body.strip() else RegisterRequest()
    except ValueError as exc:
        return error(422, f"body must be JSON {{'robot_id': str, 'args': {{...}}}}: {exc}")
    session = state.sessions.create("http", robot_id=payload.robot_id, args=payload.args)
    return JSONResponse({"session_id": session.id}, status_code=201)


@router.post("/unregister")
async def unregister(request: Request, x_session_id: str | None = Header(default=None)) -> Response:
    state = state_of(request)
    session = session_of(state, x_session_id)
    if isinstance(session, JSONResponse):
        return session
    state.close_session(session, "the session was unregistered")
    return JSONResponse(session.stats())


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


@router.post("/send_image")
async def send_image(
    request: Request,
    wait: bool = False,
    x_session_id: str | None = Header(default=None),
    x_timestamp: str | None = Header(default=None),
) -> Response:
    state = state_of(request)
    recv_ns = time.monotonic_ns()
    session = session_of(state, x_session_id)
    if isinstance(session, JSONResponse):
        state.metrics.reject("http", "unknown_session")
        return session
    seq = session.take_seq()
    session.received += 1
    state.metrics.received.labels(transport="http").inc()
    try:
        content_type = request.headers.get("content-type", "").split(";")[0].strip().lower()
        if content_type not in JPEG_TYPES:
            raise FrameRejected("wrong_content_type", f"Content-Type must be image/jpeg, got {content_type!r}", 415)
        if x_timestamp is not None and not x_timestamp.lstrip("-").isdigit():
            raise FrameRejected("bad_timestamp", f"X-Timestamp must be an integer, got {x_timestamp!r}", 422)
        timestamp = int(x_timestamp) if x_timestamp is not None else time.time_ns()
        data = await read_limited(request, state.settings.max_payload_bytes)
        waiter = await state.pipeline.receive(session, timestamp, jpeg_frame(data), wait=wait, recv_ns=recv_ns, seq=seq)
    except FrameRejected as exc:
        session.rejected += 1
        state.metrics.reject("http", exc.reason)
        return error(exc.status, str(exc), timestamp=x_timestamp)
    if waiter is None:
        return JSONResponse({"timestamp": timestamp, "queued": True}, status_code=202)
    try:
        return JSONResponse(await asyncio.wait_for(waiter, state.settings.wait_timeout_s))
    except FrameDropped:
        return error(409, "frame superseded by a newer frame of this session (newest frame wins)", timestamp=timestamp)
    except SessionClosed as exc:
        return error(410, str(exc), timestamp=timestamp)
    except FrameRejected as exc:
        return error(exc.status, str(exc), timestamp=timestamp)
    except asyncio.TimeoutError:
        return error(504, f"no result within {state.settings.wait_timeout_s} s", timestamp=timestamp)


@router.get("/results")
async def results(request: Request, x_session_id: str | None = Header(default=None)) -> Response:
    state = state_of(request)
    session = session_of(state, x_session_id)
    if isinstance(session, JSONResponse):
        return session
    return JSONResponse(
        {
            "results": session.drain_results(),
            "dropped": session.dropped,
            "results_overflowed": session.results_overflowed,
        }
    )


@router.get("/healthz")
@router.get("/v2/health/live")
async def live() -> dict[str, str]:
    return {"status": "live"}


@router.get("/readyz")
@router.get("/v2/health/ready")
async def ready(request: Request) -> Response:
    pipeline = state_of(request).pipeline
    if pipeline.ready.is_set():
        return JSONResponse({"status": "ready"})
    if pipeline.load_error is not None:
        return error(503, f"model failed to load: {pipeline.load_error}")
    return error(503, "model loading")


@router.get("/v2")
async def server_metadata(request: Request) -> dict:
    """KServe v2 server metadata, plus the one model this netapp serves (so a robot can say what answered it)."""
    from netapp import __version__

    models = [state_of(request).processor.describe()]
    return {"name": "netapp-toolkit", "version": __version__, "extensions": [], "models": models}


@router.get("/v2/models/{name}")
async def model_metadata(request: Request, name: str) -> Response:
    processor = state_of(request).processor
    if name != processor.name:
        return error(404, f"unknown model {name!r}; this netapp serves {processor.name!r}")
    return JSONResponse(processor.describe())


@router.get("/v2/models/{name}/ready")
async def model_ready(request: Request, name: str) -> Response:
    state = state_of(request)
    if name != state.processor.name:
        return error(404, f"unknown model {name!r}")
    return await ready(request)


@router.get("/metrics")
async def metrics(request: Request) -> Response:
    return Response(state_of(request).metrics.render(), media_type=CONTENT_TYPE_LATEST)
