"""`/unregister` revokes a token on every replica, not only on its owner (where `/unregister` is forwarded).

Any replica takes a token's `?wait=true` frames where they land, so one that serves a token another replica issued
(its owner) asks the owner whether the robot unregistered there (`GET /cluster/revoked`), before its first frame and
then at most every `CHECK_EVERY_S`: a revoked token is refused here too from then on, within that bound. The owner
is asked at an address taken only from the token's signature (`netapp.server.cluster.ownership`), never from what a
client sends. An owner out of reach revokes nothing: the frame is served, as before.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING

from netapp.protocol import FORWARDED_HEADER, SESSION_HEADER
from netapp.server.cluster.ownership import Cluster
from netapp.server.cluster.peer_tls import PeerTLS
from netapp.server.sessions import Session

if TYPE_CHECKING:  # imported on first use: most netapps are no cluster, and httpx costs their start-up 50 ms
    import httpx

log = logging.getLogger(__name__)

REVOKED_PATH = "/cluster/revoked"  # the owner answers {"revoked": bool} for the token in X-Session-Id
CHECK_EVERY_S = 2.0  # longest a revoked token is still served on a replica that is not its owner
ASK_TIMEOUT_S = 1.0


class RevocationCheck:
    def __init__(self, cluster: Cluster, peers: PeerTLS, every_s: float = CHECK_EVERY_S) -> None:
        self.cluster = cluster
        self.peers = peers
        self.every_s = every_s
        self._client: httpx.AsyncClient | None = None

    async def revoked(self, session: Session) -> bool:
        """Whether `session`'s token was unregistered at its owner, asked at most every `every_s` per session."""
        claims = self.cluster.open_session_token(session.id)
        owner = self.cluster.remote(claims.owner) if claims is not None else None
        now = time.monotonic()
        if owner is None or now - session.owner_asked_s < self.every_s:
            return False
        session.owner_asked_s = now
        import httpx

        if self._client is None:  # made on the server's event loop, on first use
            self._client = httpx.AsyncClient(timeout=ASK_TIMEOUT_S, verify=self.peers.verify)
        try:
            answer = await self._client.get(
                owner + REVOKED_PATH, headers={SESSION_HEADER: session.id, FORWARDED_HEADER: "1"}
            )
            return answer.status_code == 200 and answer.json().get("revoked") is True
        except (httpx.HTTPError, ValueError, AttributeError) as exc:
            if self.peers.refused(owner, exc):
                return False
            log.debug("could not ask %s about a session: %s", owner, exc)
            return False

    async def close(self) -> None:
        if self._client is not None:
            await self._client.aclose()
            self._client = None
