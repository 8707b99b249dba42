"""The netapp's errors (`netapp.server.errors`) as HTTP answers, mapped here once: the status, the stable reason, the
message, Retry-After for what may be retried, and what else the error body says (e.g. the session cap's `limit`)."""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse

from netapp.http_errors import HTTPError
from netapp.server.errors import ServingError, refusal_fields


def http_error(exc: ServingError, **context: Any) -> HTTPError:
    """`exc` as the one error body, with what a program reads of a refusal (`retry_after_s` too, beside the
    Retry-After header: the same fields as a Socket.IO command_error); `context` adds to it (a frame's `timestamp`)."""
    retry = exc.retry_after_s
    headers = {"Retry-After": str(retry)} if retry is not None else None
    fields = {k: v for k, v in refusal_fields(exc).items() if k != "reason"}
    return HTTPError(exc.status, exc.reason, str(exc), headers=headers, **fields, **context)


async def _serving_error(request: Request, exc: ServingError) -> JSONResponse:
    return http_error(exc).response()


def install(app: FastAPI) -> None:
    """Answer whatever a route lets through of the dataplane's errors (a frame's own carry its timestamp: the frame
    routes map those themselves)."""
    app.add_exception_handler(ServingError, _serving_error)
