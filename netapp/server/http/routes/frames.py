"""The paper's HTTP frames: POST /send_image (a JPEG; its result now with ?wait=true, else polled) and GET /results.

A frame refused before it is queued answers with its X-Timestamp as sent; what became of a queued frame (dropped,
late, its session closed) with the timestamp it was queued under.

`POST /send_image` is the per-frame route: a `LeanRoute` (`netapp/server/http/lean_route.py`), so FastAPI describes
it from `_described` and `send_image` reads the request itself.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Request
from fastapi.responses import JSONResponse

from netapp.frame import JPEG, EncodedFrame
from netapp.protocol import DEADLINE_HEADER, ROBOT_LATENCY_HEADER, parse_deadline_ms
from netapp.server.dataplane import LATENCY_META, DataPlane, IncomingFrame
from netapp.server.decoding.jpeg import jpeg_frame
from netapp.server.errors import FrameError, FrameRejected
from netapp.server.http.body import parse_timestamp, read_limited
from netapp.server.http.dependencies import TRANSPORT, FrameSession, HTTPSession, Plane, frame_session
from netapp.server.http.errors import http_error
from netapp.server.http.json_response import WireJSONResponse
from netapp.server.http.lean_route import lean_route, query_flag
from netapp.server.http.schemas import PolledResults, Queued
from netapp.server.settings import Settings
from netapp.tracecontext import TRACEPARENT, TRACESTATE

router = APIRouter()
JPEG_TYPES = {"image/jpeg", "image/jpg"}


async def send_image(request: Request) -> WireJSONResponse:
    """One frame: its session (`frame_session`), then `parse` (headers, the body bounded in size and time, the
    JPEG's header) inside `DataPlane.submit`; with ?wait=true its result, else 202 and polling."""
    plane: DataPlane = request.app.state.dataplane
    settings: Settings = request.app.state.settings
    headers = request.headers
    session = await frame_session(plane, settings, headers.get("authorization"), headers.get("x-session-id"))
    wait = query_flag(request, "wait")
    x_timestamp = headers.get("x-timestamp")

    async def parse() -> IncomingFrame:
        frame = await http_frame(request, settings)
        return IncomingFrame(frame, jpeg_frame(frame.payload, settings.max_pixels))

    try:
        accepted = await plane.submit(session, TRANSPORT, parse, wait=wait)
    except FrameRejected as exc:  # counted by the dataplane
        shown = x_timestamp if x_timestamp is None or len(x_timestamp) <= 40 else None
        raise http_error(exc, timestamp=shown) from exc
    if accepted.waiter is None:
        return WireJSONResponse(Queued(timestamp=accepted.timestamp).model_dump(), 202)
    try:
        message = await plane.result(session, accepted)
    except FrameError as exc:  # counted by the pipeline
        raise http_error(exc, timestamp=accepted.timestamp) from exc
    return WireJSONResponse(message)


async def http_frame(request: Request, settings: Settings) -> EncodedFrame:
    """HTTP's edge: the request's headers and body -> its frame (a JPEG); FrameRejected saying what is wrong."""
    headers = request.headers
    content_type = headers.get("content-type", "").split(";")[0].strip().lower()
    if content_type not in JPEG_TYPES:
        raise FrameRejected("wrong_content_type", f"Content-Type must be image/jpeg, got {content_type!r}", 415)
    timestamp = parse_timestamp(headers.get("x-timestamp"))
    try:
        deadline_ms = parse_deadline_ms(headers.get(DEADLINE_HEADER))
    except ValueError as exc:
        raise FrameRejected("bad_deadline", f"{DEADLINE_HEADER}: {exc}", 422) from exc
    data = await read_limited(request, settings.max_payload_bytes, settings.body_timeout_s)
    frame = EncodedFrame(JPEG, timestamp, data, deadline_ms=deadline_ms)
    return frame.with_meta(
        **{
            LATENCY_META: headers.get(ROBOT_LATENCY_HEADER),
            TRACEPARENT: headers.get(TRACEPARENT),
            TRACESTATE: headers.get(TRACESTATE),
        }
    )


async def _described(
    request: Request,
    plane: Plane,
    session: FrameSession,
    wait: bool = False,
    x_timestamp: Annotated[str | None, Header()] = None,
    x_deadline_ms: Annotated[str | None, Header(alias=DEADLINE_HEADER)] = None,
    x_robot_latency: Annotated[str | None, Header(alias=ROBOT_LATENCY_HEADER)] = None,
    traceparent: Annotated[str | None, Header(alias=TRACEPARENT)] = None,
    tracestate: Annotated[str | None, Header(alias=TRACESTATE)] = None,
) -> Queued | JSONResponse:
    # What /openapi.json says of POST /send_image (no docstring: it would become the description there); never run.
    raise NotImplementedError


router.add_api_route(
    "/send_image",
    _described,
    name="send_image",
    methods=["POST"],
    status_code=202,
    response_model=Queued,
    responses={200: {"description": "with ?wait=true: the frame's result message"}},
    route_class_override=lean_route(send_image),
)


@router.get("/results")
async def results(plane: Plane, session: HTTPSession) -> PolledResults:
    return PolledResults(**plane.poll(session))
