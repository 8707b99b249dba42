"""The paper's HTTP frames: POST /send_image (a JPEG; its result now with ?wait=true, else polled) and GET /results.

A frame refused before it is queued answers with its X-Timestamp as sent; what became of a queued frame (dropped,
late, its session closed) with the timestamp it was queued under.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Request
from fastapi.responses import JSONResponse

from netapp.protocol import DEADLINE_HEADER, ROBOT_LATENCY_HEADER, parse_deadline_ms
from netapp.server.dataplane import IncomingFrame
from netapp.server.decoding.jpeg import jpeg_frame
from netapp.server.errors import FrameError, FrameRejected
from netapp.server.http.body import parse_timestamp, read_limited
from netapp.server.http.dependencies import TRANSPORT, FrameSession, HTTPSession, Plane
from netapp.server.http.errors import http_error
from netapp.server.http.schemas import PolledResults, Queued

router = APIRouter()
JPEG_TYPES = {"image/jpeg", "image/jpg"}


@router.post(
    "/send_image",
    status_code=202,
    response_model=Queued,
    responses={200: {"description": "with ?wait=true: the frame's result message"}},
)
async def send_image(
    request: Request,
    plane: Plane,
    session: FrameSession,
    wait: bool = False,
    x_timestamp: Annotated[str | None, Header()] = None,
    x_deadline_ms: Annotated[str | None, Header(alias=DEADLINE_HEADER)] = None,
    x_robot_latency: Annotated[str | None, Header(alias=ROBOT_LATENCY_HEADER)] = None,
) -> Queued | JSONResponse:
    settings = plane.settings

    async def parse() -> IncomingFrame:
        content_type = request.headers.get("content-type", "").split(";")[0].strip().lower()
        if content_type not in JPEG_TYPES:
            raise FrameRejected("wrong_content_type", f"Content-Type must be image/jpeg, got {content_type!r}", 415)
        timestamp = parse_timestamp(x_timestamp)
        try:
            deadline_ms = parse_deadline_ms(x_deadline_ms)
        except ValueError as exc:
            raise FrameRejected("bad_deadline", f"{DEADLINE_HEADER}: {exc}", 422) from exc
        data = await read_limited(request, settings.max_payload_bytes, settings.body_timeout_s)
        decode = jpeg_frame(data, settings.max_pixels)
        return IncomingFrame(timestamp, decode, deadline_ms, robot_latency=x_robot_latency, size_bytes=len(data))

    try:
        accepted = await plane.submit(session, TRANSPORT, parse, wait=wait)
    except FrameRejected as exc:  # counted by the dataplane
        shown = x_timestamp if x_timestamp is None or len(x_timestamp) <= 40 else None
        raise http_error(exc, timestamp=shown) from exc
    if accepted.waiter is None:
        return Queued(timestamp=accepted.timestamp)
    try:
        message = await plane.result(session, accepted)
    except FrameError as exc:  # counted by the pipeline
        raise http_error(exc, timestamp=accepted.timestamp) from exc
    return JSONResponse(message)


@router.get("/results")
async def results(plane: Plane, session: HTTPSession) -> PolledResults:
    return PolledResults(**plane.poll(session))
