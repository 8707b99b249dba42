"""Who may use a netapp: an optional bearer token, checked on `/register`, on every HTTP frame and on Socket.IO
connect. Without a token (no `--token-file`, no NETAPP_TOKEN) the netapp is open to any host that reaches it.

The comparison is constant-time over bytes (`hmac.compare_digest`), so a wrong token's timing says nothing about
the right one, and a token with any character (non-ASCII included) is a 401, never a 500.
"""

from __future__ import annotations

import hmac
from collections.abc import Mapping
from typing import Annotated, Any

from fastapi import Header, Request

from netapp.http_errors import HTTPError

UNAUTHORIZED = "unauthorized"
MISSING = "this netapp requires a token: send 'Authorization: Bearer <token>' (the token the middleware gave you)"
WRONG = "wrong token: use the token the middleware gave with this netapp's URL"


def bearer(header: str | None) -> str | None:
    """The token of an `Authorization: Bearer <token>` header; None for no header or another scheme."""
    scheme, _, value = (header or "").strip().partition(" ")
    return value.strip() or None if scheme.lower() == "bearer" else None


def check(expected: str | None, presented: str | None) -> str | None:
    """None when `presented` may pass (no token is required, or it is the right one), else what is wrong."""
    if not expected:
        return None
    if not presented:
        return MISSING
    return None if hmac.compare_digest(presented.encode("utf-8", "replace"), expected.encode()) else WRONG


def socketio_token(environ: Mapping[str, Any], auth: Any) -> str | None:
    """A Socket.IO connection's token: the connect packet's `auth` ({"token": ...}), else the handshake's
    Authorization header (python-socketio's `headers=`, which browsers cannot set)."""
    if isinstance(auth, Mapping) and isinstance(auth.get("token"), str):
        return auth["token"]
    return bearer(environ.get("HTTP_AUTHORIZATION"))


def require_token(request: Request, authorization: Annotated[str | None, Header()] = None) -> None:
    """FastAPI dependency of every route a robot's session uses: 401 / `unauthorized` without the right token."""
    problem = check(request.app.state.netapp.settings.token, bearer(authorization))
    if problem is not None:
        raise HTTPError(401, UNAUTHORIZED, problem, headers={"WWW-Authenticate": "Bearer"})
