"""Optional access control: a bearer token per netapp.

Without it, any host that reaches the port may register and stream (within the limits of docs/security.md#limits).
With `Settings.token_sha256` set, every robot request needs the token whose SHA-256 that is: `/register`,
`/send_image`, `/results` and `/unregister` (`Authorization: Bearer <token>`), and the Socket.IO connection
(`auth={"token": ...}`, the same header, or `?token=` in the URL for a client that can only be given a URL). The
netapp keeps only the digest, so the value that configures it (a flag, an environment variable, a pod spec) gives
nobody the token. Health, readiness and metrics stay open for probes and monitoring.

A token also says the highest priority class its robot may claim (`granted_class`, docs/scaling.md#priorities): a
class token (`Settings.priority_tokens`) grants its class, and opens the netapp like its token does; the netapp's
token, or none on an open netapp, grants `Settings.robot_priority`.
"""

from __future__ import annotations

import hashlib
import hmac
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any
from urllib.parse import parse_qs

if TYPE_CHECKING:
    from netapp.server.settings import Settings

TOKEN_QUERY = "token"


def token_digest(token: str) -> str:
    """The SHA-256 (hex) that configures a netapp for `token`."""
    return hashlib.sha256(token.encode()).hexdigest()


def check_digest(value: str) -> str:
    """A token digest from configuration, normalised; ValueError unless 64 hex digits."""
    text = value.strip().lower()
    if len(text) != 64 or any(c not in "0123456789abcdef" for c in text):
        raise ValueError("the netapp token digest must be a SHA-256 in hex (64 digits): printf %s TOKEN | sha256sum")
    return text


def allows(token_sha256: str | None, token: str | None) -> bool:
    """Whether a request with `token` may go on: always without a configured digest."""
    if token_sha256 is None:
        return True
    return token is not None and hmac.compare_digest(token_digest(token).encode(), token_sha256.encode())


def granted_class(settings: Settings, token: str | None) -> int | None:
    """The highest priority class a robot presenting `token` may claim; None when the token opens nothing here."""
    if token is not None and settings.priority_tokens:
        digest = token_digest(token).encode()
        for class_digest, granted in settings.priority_tokens.items():
            if hmac.compare_digest(class_digest.encode(), digest):
                return granted
    return settings.robot_priority if allows(settings.token_sha256, token) else None


def bearer(authorization: str | None) -> str | None:
    """The token of an `Authorization: Bearer <token>` header."""
    scheme, _, token = (authorization or "").partition(" ")
    return token.strip() or None if scheme.lower() == "bearer" else None


def socketio_token(environ: Mapping[str, Any], auth: Any) -> str | None:
    """A Socket.IO connection's token: its `auth` payload, its Authorization header, or `?token=` in its URL."""
    if isinstance(auth, Mapping) and isinstance(auth.get(TOKEN_QUERY), str):
        return auth[TOKEN_QUERY]
    return connection_token(environ.get("HTTP_AUTHORIZATION"), environ.get("QUERY_STRING", ""))


def connection_token(authorization: str | None, query_string: str) -> str | None:
    """A WebSocket's token: its Authorization header, or `?token=` in its URL."""
    header = bearer(authorization)
    if header is not None:
        return header
    values = parse_qs(query_string).get(TOKEN_QUERY)
    return values[0] if values else None
