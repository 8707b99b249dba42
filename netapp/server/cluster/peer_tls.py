"""TLS between replicas: a replica that advertises an `https://` address is reached over TLS, and its certificate is
verified before anything is forwarded to it (docs/security.md#tls-between-replicas).

What identifies a replica is a certificate the peer CA file vouches for (`netapp serve --peer-ca`, else the
replica's own `--tls-cert`: replicas of one Deployment share one certificate, which then vouches for itself). The
host name is not checked: a replica is reached at its pod IP, which no certificate of a Deployment names, and that
address comes only from an id signed with the replicas' shared key (`netapp.server.cluster.ownership`). A peer whose
certificate is refused is logged (one line naming it and why) and counted (`netapp_peer_tls_refused_total`); the
request it was for is answered as for an owner that is gone.
"""

from __future__ import annotations

import logging
import ssl

from prometheus_client import Counter

log = logging.getLogger(__name__)

CERTIFICATE = "certificate"  # the peer's certificate is not one the CA file vouches for
HANDSHAKE = "handshake"  # any other TLS failure (a plain-HTTP peer at an https:// address, no common cipher, ...)
REFUSALS = (CERTIFICATE, HANDSHAKE)


def peer_context(ca_file: str) -> ssl.SSLContext:
    """The TLS context a replica connects to the others with: their certificates verified against `ca_file`;
    OSError or ssl.SSLError when the file cannot be read or holds no certificate."""
    context = ssl.create_default_context(ssl.Purpose.SERVER_AUTH, cafile=ca_file)
    context.check_hostname = False  # a pod IP, vouched for by the shared key's signature, not by a name
    # a certificate in the file is trusted as itself, not only a root: the replicas' own shared certificate
    context.verify_flags |= ssl.VERIFY_X509_PARTIAL_CHAIN
    return context


def tls_error(exc: BaseException) -> ssl.SSLError | None:
    """The TLS error inside `exc` (httpx and websockets wrap it in their own), if it is one."""
    seen: BaseException | None = exc
    for _ in range(8):  # a chain of causes is short; bounded all the same
        if seen is None or isinstance(seen, ssl.SSLError):
            return seen
        seen = seen.__cause__ or seen.__context__
    return None


class PeerTLS:
    """How a replica connects to the others: `verify` for httpx, `websocket_ssl` for a relayed WebSocket, and
    `refused` to log and count a peer the handshake refused."""

    def __init__(self, ca_file: str | None, counter: Counter) -> None:
        self.context = peer_context(ca_file) if ca_file else None
        self.counter = counter  # labelled by reason: certificate, handshake
        for reason in REFUSALS:
            counter.labels(reason=reason)  # present at 0 from the start

    @property
    def verify(self) -> ssl.SSLContext | bool:
        """httpx's `verify`: the peer context, else the system's CAs (a replica with no peer CA)."""
        return self.context if self.context is not None else True

    def websocket_ssl(self, url: str) -> ssl.SSLContext | None:
        """The `ssl` of a `websockets` connection to `url` (none for ws://, which takes no TLS context)."""
        return self.context if url.startswith("wss://") else None

    def refused(self, peer: str, exc: BaseException) -> bool:
        """Whether `exc` is the TLS handshake with `peer` failing; if so it is logged and counted."""
        error = tls_error(exc)
        if error is None:
            return False
        if isinstance(error, ssl.SSLCertVerificationError):
            self.counter.labels(reason=CERTIFICATE).inc()
            log.warning(
                "refused the replica at %s: its TLS certificate is not one --peer-ca vouches for (%s)",
                peer,
                error.verify_message or error,
            )
        else:
            self.counter.labels(reason=HANDSHAKE).inc()
            log.warning("TLS with the replica at %s failed: %s (does it serve HTTPS?)", peer, error.reason or error)
        return True
