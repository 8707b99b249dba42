"""A route that FastAPI describes but Starlette runs: for the per-frame route, where FastAPI's own work is most of
the route's cost.

FastAPI solves an endpoint's dependencies and validates its parameters on every request (about 0.1 to 0.2 ms, the
most of any step the netapp takes on an HTTP frame before its decoding: docs/benchmarks.md#per-frame-overhead). A
`LeanRoute` keeps the endpoint's signature for /openapi.json only; each request goes straight to its `handler`,
which reads what it needs from the Request itself. Errors still go through the app's exception handlers.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import Any

from fastapi.exceptions import RequestValidationError
from fastapi.routing import APIRoute
from starlette.requests import Request
from starlette.responses import Response

Handler = Callable[[Request], Awaitable[Response]]

# What pydantic (FastAPI's validation) reads as a boolean query parameter.
_TRUE = frozenset({"1", "on", "t", "true", "y", "yes"})
_FALSE = frozenset({"0", "off", "f", "false", "n", "no"})


def lean_route(handler: Handler) -> type[APIRoute]:
    """An APIRoute class (`add_api_route(..., route_class_override=...)`) that runs `handler` for each request."""

    class LeanRoute(APIRoute):
        def get_route_handler(self) -> Callable[[Request], Any]:
            return handler

    return LeanRoute


def query_flag(request: Request, name: str, default: bool = False) -> bool:
    """A boolean query parameter read as FastAPI reads one (a 422 of the same body when it is not one)."""
    text = request.query_params.get(name)
    if text is None:
        return default
    value = text.strip().lower()
    if value in _TRUE or value in _FALSE:
        return value in _TRUE
    problem = {"loc": ("query", name), "msg": "Input should be a valid boolean, unable to interpret input"}
    raise RequestValidationError([problem | {"type": "bool_parsing", "input": text}])
