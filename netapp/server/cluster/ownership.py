"""Which replica owns what, without a shared store: ids signed with a key the replicas share.

A Kubernetes Service sends each new TCP connection to any ready replica, so a robot's requests land anywhere.
Two kinds of signed id make that work:

- An HTTP session token (`X-Session-Id`) is the session itself: robot id, args and owner, signed. Any replica
  accepts it and processes the frame where it lands (`wait=true` results come back inline); the results of frames
  sent for polling live with the owner, so those requests go to the owner.
- An Engine.IO session id is the usual random id plus its owner's address, signed. A replica that gets a request
  or a WebSocket of a session it does not own forwards it to the owner (`netapp.server.cluster.forwarding`).

Only a signature made with the shared key vouches for an address: a forged id can never make a replica connect to
an address of the sender's choice (no SSRF). Without a shared key a replica signs with a key of its own, made at
start, so its ids are good on itself only: one replica, no forwarding (the behaviour before replicas).
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import hmac
import json
import secrets
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlsplit

SIGNATURE_BYTES = 16  # HMAC-SHA256 truncated to 128 bits: plenty against forgery, short in every URL
MAX_ARGS_BYTES = 4096  # a token carries the session's args in a header on every request: bounded


def _b64(data: bytes) -> str:
    return base64.urlsafe_b64encode(data).rstrip(b"=").decode()


def _unb64(text: str) -> bytes:
    return base64.urlsafe_b64decode(text + "=" * (-len(text) % 4))


def check_advertise_url(url: str) -> str:
    """The address other replicas reach this one at (http://POD_IP:PORT), normalised; ValueError when unusable."""
    parts = urlsplit(url)
    if parts.scheme not in ("http", "https") or not parts.hostname or parts.path not in ("", "/"):
        raise ValueError(f"--advertise-url must look like http://POD_IP:PORT, got {url!r}")
    return f"{parts.scheme}://{parts.netloc}"


@dataclass(frozen=True)
class SessionClaims:
    """What an HTTP session token says."""

    owner: str | None  # the replica that keeps its polled results (None: one replica, no forwarding)
    robot_id: str | None
    args: dict[str, Any]


@dataclass(frozen=True)
class Cluster:
    key: bytes
    advertise_url: str | None = None
    shared: bool = False  # the key is shared with other replicas: ids carry owners, requests are forwarded

    @classmethod
    def build(cls, key: bytes | None, advertise_url: str | None) -> Cluster:
        """With a shared key: a replica among replicas (it needs its own address). Without: on its own."""
        if not key:
            return cls(secrets.token_bytes(32))
        if not advertise_url:
            raise ValueError("a cluster key needs --advertise-url http://POD_IP:PORT (how the other replicas reach it)")
        if len(key) < 16:
            raise ValueError("the cluster key is too short: use 32 random bytes (e.g. `openssl rand -hex 32`)")
        return cls(key, check_advertise_url(advertise_url), True)

    def _signature(self, body: str) -> str:
        return _b64(hmac.new(self.key, body.encode(), hashlib.sha256).digest()[:SIGNATURE_BYTES])

    def _verified(self, signed: str | None) -> str | None:
        """The body of `body.signature` when the signature is ours; None for anything else."""
        if not signed:
            return None
        body, _, signature = signed.rpartition(".")
        if not body or not hmac.compare_digest(signature.encode(), self._signature(body).encode()):
            return None
        return body

    def remote(self, owner: str | None) -> str | None:
        """`owner` when it is another replica this one should forward to; None when the work is local."""
        return owner if self.shared and owner and owner != self.advertise_url else None

    # -- HTTP session tokens ----------------------------------------------------------------------------------

    def session_token(self, robot_id: str | None, args: dict[str, Any]) -> str:
        """A new HTTP session, owned by this replica. ValueError when its args are too large to carry."""
        encoded_args = json.dumps(args, separators=(",", ":"))
        if len(encoded_args) > MAX_ARGS_BYTES:
            raise ValueError(f"args are {len(encoded_args)} bytes of JSON, over the {MAX_ARGS_BYTES}-byte limit")
        claims = {"n": secrets.token_hex(8), "o": self.advertise_url, "r": robot_id, "a": args}
        body = _b64(json.dumps(claims, separators=(",", ":")).encode())
        return f"{body}.{self._signature(body)}"

    def open_session_token(self, token: str | None) -> SessionClaims | None:
        """The claims of a token this cluster signed; None for a forged, foreign or malformed one."""
        body = self._verified(token)
        if body is None:
            return None
        try:
            claims = json.loads(_unb64(body))
        except (ValueError, binascii.Error):
            return None
        if not isinstance(claims, dict) or not isinstance(claims.get("a"), dict):
            return None
        return SessionClaims(owner=claims.get("o"), robot_id=claims.get("r"), args=claims["a"])

    # -- Engine.IO session ids --------------------------------------------------------------------------------

    def engineio_sid(self, random_id: str) -> str:
        """Engine.IO's random sid, plus this replica's address, signed (unchanged on a replica on its own)."""
        if not self.shared:
            return random_id
        body = f"{random_id}.{_b64(self.advertise_url.encode())}"
        return f"{body}.{self._signature(body)}"

    def engineio_owner(self, sid: str | None) -> str | None:
        """The owner named by a sid this cluster signed; None for any other sid."""
        body = self._verified(sid) if self.shared else None
        if body is None or "." not in body:
            return None
        try:
            return _unb64(body.rpartition(".")[2]).decode()
        except (ValueError, binascii.Error):
            return None
