"""Robot credentials and bearer tokens.

Secrets are stored only as scrypt hashes (``scrypt$n$r$p$salt$hash``, base64url parts); tokens are HMAC-SHA256 signed
``payload.signature`` strings with an expiry, so the middleware keeps no session table, and a restart with the
same signing key keeps robots' tokens valid.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import json
import secrets
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from netapp.protocol import DEFAULT_PRIORITY, PRIORITY_CLASSES, parse_priority

# scrypt cost: n=2**14, r=8 takes ~50 ms and 16 MiB here; logins are rare because tokens are reused.
SCRYPT_N, SCRYPT_R, SCRYPT_P = 2**14, 8, 1
DEFAULT_TOKEN_TTL_S = 3600.0
MIN_TOKEN_KEY_BYTES = 32  # HMAC-SHA256 keys shorter than its output weaken it


class AuthError(Exception):
    """Bad credentials or a bad, expired or forged token."""


def _b64(data: bytes) -> str:
    return base64.urlsafe_b64encode(data).rstrip(b"=").decode()


def _unb64(text: str) -> bytes:
    return base64.urlsafe_b64decode(text + "=" * (-len(text) % 4))


def hash_secret(secret: str, *, n: int = SCRYPT_N, r: int = SCRYPT_R, p: int = SCRYPT_P) -> str:
    """Hash a robot secret for the robots file."""
    salt = secrets.token_bytes(16)
    digest = hashlib.scrypt(secret.encode(), salt=salt, n=n, r=r, p=p, maxmem=256 * 1024 * 1024, dklen=32)
    return f"scrypt${n}${r}${p}${_b64(salt)}${_b64(digest)}"


def verify_secret(secret: str, hashed: str) -> bool:
    """True when `secret` matches `hashed` (constant-time compare); a malformed hash never matches."""
    try:
        scheme, n, r, p, salt, digest = hashed.split("$")
        if scheme != "scrypt":
            return False
        expected = _unb64(digest)
        actual = hashlib.scrypt(
            secret.encode(),
            salt=_unb64(salt),
            n=int(n),
            r=int(r),
            p=int(p),
            maxmem=256 * 1024 * 1024,
            dklen=len(expected),
        )
    except (ValueError, TypeError):
        return False
    return hmac.compare_digest(actual, expected)


def _robot_entries(data: Any) -> dict[str, Mapping[str, Any]]:
    """Robots document -> {robot_id: {"secretHash": ..., "priority"?: ...}} (see `parse_robots`)."""
    if isinstance(data, Mapping) and "robots" in data:
        data = data["robots"]
    if data is None:
        return {}
    if isinstance(data, list):
        try:
            data = {str(item["id"]): item for item in data}
        except (KeyError, TypeError) as exc:
            raise ValueError(f"each robot in a list needs 'id' and 'secretHash': {exc}") from exc
    if not isinstance(data, Mapping):
        raise ValueError("the robots document must be a map of robot id -> hashed secret")
    entries = {str(k): v if isinstance(v, Mapping) else {"secretHash": v} for k, v in data.items()}
    for robot_id, entry in entries.items():
        if "secretHash" not in entry:
            raise ValueError(f"robot {robot_id!r} needs a secretHash")
    return entries


def parse_robots(data: Any) -> dict[str, str]:
    """Robots document -> {robot_id: hashed secret}.

    Accepted shapes: ``{robot_id: hash}``, ``{robot_id: {"secretHash": hash, "priority": class}}``,
    ``{"robots": {...}}`` or ``{"robots": [{"id": robot_id, "secretHash": hash, "priority": class}]}`` (a bare
    list works too); `priority` is optional (`robot_priorities`).
    """
    robots = {robot_id: str(entry["secretHash"]) for robot_id, entry in _robot_entries(data).items()}
    for robot_id, hashed in robots.items():
        if not hashed.startswith("scrypt$"):
            raise ValueError(f"robot {robot_id!r}: secret is not a scrypt hash (use `netapp middleware hash-secret`)")
    return robots


def robot_priorities(data: Any) -> dict[str, str]:
    """Robots document -> {robot_id: priority class} of the robots that have one (docs/scaling.md#priorities)."""
    classes = {}
    for robot_id, entry in _robot_entries(data).items():
        if entry.get("priority") is not None:
            classes[robot_id] = PRIORITY_CLASSES[parse_priority(entry["priority"])]  # ValueError naming the classes
    return classes


@dataclass(frozen=True)
class TokenClaims:
    robot_id: str
    issued_at: float
    expires_at: float


class TokenSigner:
    """Issues and verifies HMAC-signed, expiring bearer tokens."""

    def __init__(
        self, key: bytes | None = None, ttl_s: float = DEFAULT_TOKEN_TTL_S, clock: Callable[[], float] = time.time
    ) -> None:
        # Without a configured key, tokens die with the process: robots simply log in again.
        if key is not None and len(key) < MIN_TOKEN_KEY_BYTES:
            raise ValueError(
                f"the token key has {len(key)} bytes, at least {MIN_TOKEN_KEY_BYTES} are needed: "
                "make one with `head -c 48 /dev/urandom | base64`"
            )
        self._key = key if key is not None else secrets.token_bytes(MIN_TOKEN_KEY_BYTES)
        self.ttl_s = ttl_s
        self._clock = clock

    def issue(self, robot_id: str, ttl_s: float | None = None) -> tuple[str, TokenClaims]:
        now = self._clock()
        claims = TokenClaims(robot_id=robot_id, issued_at=now, expires_at=now + (ttl_s or self.ttl_s))
        payload = _b64(json.dumps({"sub": robot_id, "iat": now, "exp": claims.expires_at}).encode())
        return f"{payload}.{self._sign(payload)}", claims

    def verify(self, token: str) -> TokenClaims:
        payload, _, signature = token.partition(".")
        # As bytes: compare_digest refuses str with non-ASCII characters (a 500 instead of a 401).
        if not signature or not hmac.compare_digest(signature.encode(), self._sign(payload).encode()):
            raise AuthError("invalid token")
        try:
            body = json.loads(_unb64(payload))
            claims = TokenClaims(robot_id=str(body["sub"]), issued_at=float(body["iat"]), expires_at=float(body["exp"]))
        except (ValueError, KeyError, TypeError) as exc:
            raise AuthError("invalid token") from exc
        if claims.expires_at <= self._clock():
            raise AuthError("token expired")
        return claims

    def netapp_token(self, name: str) -> str:
        """The bearer token of the NetApp `name`: derived from this key, so a restart hands out the same one."""
        return _b64(hmac.new(self._key, b"netapp-token:" + name.encode(), hashlib.sha256).digest())

    def _sign(self, payload: str) -> str:
        return _b64(hmac.new(self._key, payload.encode(), hashlib.sha256).digest())


class RobotRegistry:
    """Checks robot credentials against a source that may change while running (a mounted Secret); and says each
    robot's priority class (`priorities`: the same document's, by `robot_priorities`)."""

    def __init__(self, load: Callable[[], dict[str, str]], priorities: Callable[[], dict[str, str]] = dict) -> None:
        self._load = load
        self._priorities = priorities

    def priority(self, robot_id: str) -> str:
        """The robot's class in the robots file (the netapp's default, normal, where it has none)."""
        return self._priorities().get(robot_id, DEFAULT_PRIORITY)

    def known(self, robot_id: str) -> bool:
        return robot_id in self._load()

    def authenticate(self, robot_id: str, secret: str) -> None:
        hashed = self._load().get(robot_id)
        # Hash anyway for an unknown robot, so the response time does not reveal which ids exist.
        if not verify_secret(secret, hashed or _DUMMY_HASH) or hashed is None:
            raise AuthError("unknown robot or wrong secret")


_DUMMY_HASH = hash_secret(secrets.token_hex(8))
