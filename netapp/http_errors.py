"""Errors mapped once, for every FastAPI app of the project (the netapp and the middleware).

Routes and dependencies raise `HTTPError` (or FastAPI's own HTTPException and validation errors); `install()` maps
each to the one error body of `netapp.protocol.error_body`, so a client needs one parser for both services.
"""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from netapp.protocol import error_body

# Stable `reason` codes for the statuses FastAPI raises by itself.
_REASONS = {
    400: "bad_request",
    401: "unauthorized",
    403: "forbidden",
    404: "not_found",
    405: "method_not_allowed",
    409: "conflict",
    413: "payload_too_large",
    415: "unsupported_media_type",
    422: "invalid_request",
    429: "too_many_requests",
    500: "internal_error",
    503: "unavailable",
}


class HTTPError(Exception):
    """An answer other than 2xx: `status`, a stable `reason` code, a message that says what to do, and context."""

    def __init__(
        self, status: int, reason: str, message: str, /, *, headers: dict[str, str] | None = None, **extra: Any
    ) -> None:
        super().__init__(message)
        self.status = status
        self.reason = reason
        self.headers = headers
        self.extra = extra

    def response(self) -> JSONResponse:
        return JSONResponse(error_body(str(self), self.reason, **self.extra), self.status, headers=self.headers)


def reason_for(status: int) -> str:
    return _REASONS.get(status, "error")


async def _http_error(request: Request, exc: HTTPError) -> JSONResponse:
    return exc.response()


async def _starlette_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
    message = exc.detail if isinstance(exc.detail, str) else str(exc.detail)
    return JSONResponse(
        error_body(message, reason_for(exc.status_code)), exc.status_code, headers=getattr(exc, "headers", None)
    )


async def _validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
    problems = "; ".join(
        f"{'.'.join(str(p) for p in e.get('loc', ()) if p != 'body') or 'body'}: {e.get('msg')}" for e in exc.errors()
    )
    return JSONResponse(error_body(f"invalid request: {problems}", "invalid_request"), 422)


def install(app: FastAPI) -> None:
    """Map every error type to the one body, once per app."""
    app.add_exception_handler(HTTPError, _http_error)
    app.add_exception_handler(StarletteHTTPException, _starlette_error)
    app.add_exception_handler(RequestValidationError, _validation_error)
