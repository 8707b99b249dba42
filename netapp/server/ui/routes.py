"""The pages' routes: two HTML pages and their script (files beside this module), a JSON list of the robots, one
robot's history, and a Server-Sent Events stream of its frames and results while a page is open."""

from __future__ import annotations

import asyncio
import base64
import json
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Annotated, Any

import cv2
from fastapi import APIRouter, Depends, Request
from fastapi.responses import FileResponse, StreamingResponse

from netapp.http_errors import HTTPError
from netapp.protocol import RESULT_FIELDS
from netapp.results import CLASSIFICATIONS_FIELD, COCO_SKELETON, KEYPOINT_MIN_SCORE, MASK_ALPHA
from netapp.server import access
from netapp.server.http.dependencies import Services
from netapp.server.ui.live import LiveView, RobotView

STATIC = Path(__file__).resolve().parent / "static"
PAGE_FILES = {
    "ui.js": "text/javascript",
    "draw.js": "text/javascript",
    "camera.js": "text/javascript",
    "ui.css": "text/css",
}
MAX_EVENTS_PER_S = 10.0  # a page needs no more; bounds the encoding one watcher can cause
KEEPALIVE_S = 15.0
JPEG_QUALITY = 75
MAX_OUTPUT_CHARS = 2000  # of a custom processor's output shown on the page
MAX_PAGE_WIDTH = 960  # frames wider than this are scaled down for the page (boxes stay in frame pixels)
# How the page draws masks and poses, the same as the robot's drawing (netapp/results.py): sent once per page.
STYLE = {"mask_alpha": MASK_ALPHA, "keypoint_min_score": KEYPOINT_MIN_SCORE, "coco_skeleton": COCO_SKELETON}

router = APIRouter(prefix="/ui", include_in_schema=False)
camera_router = APIRouter(include_in_schema=False)


def live_of(services: Services, request: Request) -> LiveView:
    """The pages' view, for a request that carries this netapp's token when it has one (a robot's frames are
    no more open than its stream): `Authorization: Bearer`, or `?token=` since a page cannot set headers."""
    token = access.bearer(request.headers.get("authorization")) or request.query_params.get(access.TOKEN_QUERY)
    if not access.allows(services.settings.token_sha256, token):
        raise HTTPError(401, "unauthorized", "this netapp needs its token: open /ui?token=TOKEN")
    return request.app.state.live


Live = Annotated[LiveView, Depends(live_of)]


def robot_of(live: LiveView, view_id: str) -> RobotView:
    view = live.get(view_id)
    if view is None:
        raise HTTPError(404, "unknown_robot", f"no robot {view_id!r} is connected now: see /ui for those that are")
    return view


@router.get("")
@router.get("/robot/{view_id}")
async def page() -> FileResponse:
    """The list or a robot's view: one page, its script shows what the path names."""
    return FileResponse(STATIC / "page.html", media_type="text/html")


@camera_router.get("/camera")
async def camera_page() -> FileResponse:
    """This browser's camera to the netapp over WebRTC, its results drawn live (docs/cameras.md#webrtc); the offer
    it sends needs the netapp's token (`/camera?token=TOKEN`) as any robot's frames do."""
    return FileResponse(STATIC / "camera.html", media_type="text/html")


@router.get("/static/{name}")
async def static_file(name: str) -> FileResponse:
    if name not in PAGE_FILES:  # a fixed list: no path from the request reaches the file system
        raise HTTPError(404, "not_found", f"no file {name!r}")
    return FileResponse(STATIC / name, media_type=PAGE_FILES[name])


@router.get("/api/robots")
async def robots(live: Live) -> dict[str, Any]:
    return {"robots": [view.summary() for view in live.robots()]}


@router.get("/api/robots/{view_id}")
async def robot(live: Live, view_id: str) -> dict[str, Any]:
    view = robot_of(live, view_id)
    return {**view.summary(), "history": [_entry(h) for h in view.history]}


@router.get("/api/robots/{view_id}/events")
async def events(live: Live, view_id: str) -> StreamingResponse:
    view = robot_of(live, view_id)
    if live.total_watchers() >= live.max_watchers:
        raise HTTPError(429, "too_many_watchers", f"{live.max_watchers} pages are open already: close one")
    live.watch(view)  # from now on its frames are kept; released when the page goes

    async def stream() -> AsyncIterator[bytes]:
        try:
            sent = 0
            yield b"retry: 1000\n\n"
            yield _sse({"style": STYLE})
            while not view.session.closed:
                view.changed.clear()
                if view.latest is not None and view.version != sent:
                    sent = view.version
                    yield _sse(await _event(view))
                    await asyncio.sleep(1 / MAX_EVENTS_PER_S)  # pacing the page, not synchronisation
                    continue
                try:
                    await asyncio.wait_for(view.changed.wait(), KEEPALIVE_S)
                except asyncio.TimeoutError:
                    yield b": keep-alive\n\n"
            yield _sse({"gone": True})
        finally:
            live.unwatch(view)

    return StreamingResponse(stream(), media_type="text/event-stream", headers={"Cache-Control": "no-store"})


async def _event(view: RobotView) -> dict[str, Any]:
    version = view.version
    image, message = view.latest
    if view.encoded is None or view.encoded[0] != version:  # one encoding per result, whatever the watchers
        view.encoded = (version, await asyncio.to_thread(_jpeg, image))
    height, width = image.shape[:2]
    detections = message.get("detections")
    classifications = message.get(CLASSIFICATIONS_FIELD)
    # a custom processor's own fields (classifications are drawn, not printed)
    output = {k: v for k, v in message.items() if k not in RESULT_FIELDS and k != CLASSIFICATIONS_FIELD}
    output_text = json.dumps(output, default=str)
    return {
        "frame": "data:image/jpeg;base64," + base64.b64encode(view.encoded[1]).decode(),
        "width": width,
        "height": height,
        "timestamp": message.get("timestamp"),
        "detections": detections if isinstance(detections, list) else [],
        "classifications": classifications if isinstance(classifications, list) else [],
        "output": output_text if len(output_text) <= MAX_OUTPUT_CHARS else output_text[: MAX_OUTPUT_CHARS - 3] + "...",
        "stats": view.summary(),
        "latency": _entry(view.history[-1]) if view.history else None,
    }


def _jpeg(image) -> bytes:
    height, width = image.shape[:2]
    if width > MAX_PAGE_WIDTH:
        image = cv2.resize(
            image, (MAX_PAGE_WIDTH, round(height * MAX_PAGE_WIDTH / width)), interpolation=cv2.INTER_AREA
        )
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise ValueError("could not encode the frame for the page")
    return buf.tobytes()


def _entry(entry: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in entry.items() if k != "at"}


def _sse(payload: dict[str, Any]) -> bytes:
    return f"data: {json.dumps(payload, default=str)}\n\n".encode()
