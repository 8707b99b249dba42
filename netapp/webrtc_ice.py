"""WebRTC's ICE for both sides (the netapp and `netapp stream --transport webrtc`): which STUN/TURN servers, and which
of this machine's addresses are offered as host candidates. aiortc is the `webrtc` extra; nothing here imports it
until a peer is made.

Two defaults of aiortc are changed on purpose:
- with no `iceServers` it asks Google's public STUN server; here an empty list is always passed, so no server is
  contacted unless one is named (`--ice-server`);
- aioice offers every address but loopback (RFC 8445); `restrict_host_addresses` narrows that to the addresses
  named (a netapp on `--host 127.0.0.1` offers 127.0.0.1 only, and so binds nothing else).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

EXTRA_HINT = "pip install 'netapp-toolkit[webrtc]'"
MISSING_MESSAGE = f"WebRTC needs aiortc, which is not installed here: {EXTRA_HINT}"
ICE_SCHEMES = ("stun:", "stuns:", "turn:", "turns:")
# Where a TURN server's credentials come from (never the command line, where `ps` shows them)
USERNAME_ENV = "NETAPP_ICE_USERNAME"
CREDENTIAL_ENV = "NETAPP_ICE_CREDENTIAL"
CREDENTIAL_FILE_ENV = "NETAPP_ICE_CREDENTIAL_FILE"  # a file holding the credential (a mounted Secret)


@dataclass(frozen=True)
class IceServer:
    url: str
    username: str | None = None
    credential: str | None = None

    def __repr__(self) -> str:  # the credential stays out of logs
        return f"IceServer({self.url!r}, username={self.username!r})"


def parse_ice_server(url: str, environ: dict[str, str] | None = None) -> IceServer:
    """`stun:HOST[:PORT]` or `turn:HOST[:PORT][?transport=udp|tcp]` (turns: too); a TURN server's username and
    credential from NETAPP_ICE_USERNAME and NETAPP_ICE_CREDENTIAL (or the file NETAPP_ICE_CREDENTIAL_FILE names).
    ValueError saying what to change."""
    env = os.environ if environ is None else environ
    if not url.startswith(ICE_SCHEMES) or "@" in url:
        raise ValueError(
            f"--ice-server must be stun:HOST[:PORT] or turn:HOST[:PORT] (credentials in ${USERNAME_ENV} and "
            f"${CREDENTIAL_ENV}, never in the URL), got {url[:80]!r}"
        )
    if not url.startswith("turn"):
        return IceServer(url)
    credential = env.get(CREDENTIAL_ENV)
    path = env.get(CREDENTIAL_FILE_ENV)
    if not credential and path:
        try:
            with open(path, encoding="utf-8") as file:
                credential = file.read().strip()
        except OSError as exc:
            raise ValueError(f"${CREDENTIAL_FILE_ENV} {path}: {exc.strerror}") from None
    username = env.get(USERNAME_ENV)
    if not username or not credential:
        raise ValueError(
            f"the TURN server {url} needs ${USERNAME_ENV} and ${CREDENTIAL_ENV} (or ${CREDENTIAL_FILE_ENV}) set"
        )
    return IceServer(url, username, credential)


def configuration(servers: tuple[IceServer, ...] | list[IceServer]) -> Any:
    """aiortc's RTCConfiguration naming exactly `servers` (an empty list: no STUN or TURN server at all)."""
    from aiortc import RTCConfiguration, RTCIceServer

    return RTCConfiguration(
        iceServers=[RTCIceServer(urls=s.url, username=s.username, credential=s.credential) for s in servers]
    )


def restrict_host_addresses(addresses: tuple[str, ...]) -> None:
    """Offer only `addresses` as host candidates, in this process (aioice has no option for it: its address lookup
    is wrapped). Empty: every address aioice finds, as it does by default."""
    import aioice.ice

    original = getattr(aioice.ice.get_host_addresses, "__wrapped__", aioice.ice.get_host_addresses)
    if not addresses:
        aioice.ice.get_host_addresses = original
        return
    wanted = tuple(addresses)

    def host_addresses(use_ipv4: bool, use_ipv6: bool) -> list[str]:
        return [a for a in wanted if (":" in a and use_ipv6) or (":" not in a and use_ipv4)]

    host_addresses.__wrapped__ = original  # type: ignore[attr-defined]
    aioice.ice.get_host_addresses = host_addresses


def ice_addresses_for(host: str) -> tuple[str, ...]:
    """The host candidates for a netapp listening on `host`: that address itself, or every one for a wildcard."""
    return () if host in ("0.0.0.0", "::", "") else (host,)
