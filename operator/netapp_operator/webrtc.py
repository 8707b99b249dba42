"""A NetApp's `spec.webrtc` (browsers and robots sending a WebRTC track, docs/cameras.md#webrtc): checked, and rendered
as the netapp's `--ice-server` flags and, for a TURN server, its credentials from a Secret in the environment
(never in the args, which anyone who can read the Deployment sees). Pure functions.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from netapp.webrtc_ice import CREDENTIAL_ENV, USERNAME_ENV, parse_ice_server

MAX_ICE_SERVERS = 8
TURN_SECRET_KEYS = ("username", "credential")  # the keys of spec.webrtc.turnSecret


@dataclasses.dataclass(frozen=True)
class WebRtcSpec:
    ice_servers: tuple[Any, ...] = ()
    turn_secret: Any = None


def parse_webrtc(raw: Any) -> WebRtcSpec | None:
    if raw is None:
        return None
    raw = raw if isinstance(raw, Mapping) else {}
    servers = raw.get("iceServers") or []  # (a list: `webrtc: {}` names no server, not one called "()")
    return WebRtcSpec(tuple(servers) if isinstance(servers, list) else (servers,), raw.get("turnSecret"))


def webrtc_problems(webrtc: WebRtcSpec | None) -> list[str]:
    """What is wrong with `spec.webrtc`, as sentences."""
    if webrtc is None:
        return []
    if len(webrtc.ice_servers) > MAX_ICE_SERVERS:
        return [f"spec.webrtc.iceServers takes at most {MAX_ICE_SERVERS} servers"]
    turn = False
    for url in webrtc.ice_servers:
        if not isinstance(url, str):
            return ["spec.webrtc.iceServers must be URLs such as turn:turn.example.org:3478"]
        try:  # the credentials come from the Secret: checked with stand-ins here
            parse_ice_server(url, {USERNAME_ENV: "u", CREDENTIAL_ENV: "c"})
        except ValueError as exc:
            return [f"spec.webrtc: {str(exc).replace('--ice-server', 'each of iceServers')}"]
        turn = turn or url.startswith("turn")
    if webrtc.turn_secret is not None and not (isinstance(webrtc.turn_secret, str) and webrtc.turn_secret):
        return ["spec.webrtc.turnSecret must name a Secret (keys username and credential)"]
    if turn and not webrtc.turn_secret:
        return ["spec.webrtc names a TURN server: give turnSecret, a Secret with keys username and credential"]
    return []


def default_webrtc(ice_servers: list[str] | tuple[str, ...], turn_secret: str) -> WebRtcSpec | None:
    """The operator's default `spec.webrtc` (`--ice-server`, `--turn-secret`: the chart's `operator.webrtc`), checked
    as a NetApp's is; None when neither is given. Raises ValueError, one line that names the flags."""
    if not ice_servers and not turn_secret:
        return None
    webrtc = WebRtcSpec(tuple(ice_servers), turn_secret or None)
    problems = webrtc_problems(webrtc)
    if problems:
        problem = problems[0].replace("spec.webrtc", "operator.webrtc")  # the chart's values read as a NetApp's
        raise ValueError(f"--ice-server/--turn-secret: {problem}")
    return webrtc


def effective_webrtc(own: WebRtcSpec | None, default: WebRtcSpec | None) -> WebRtcSpec | None:
    """A NetApp's own `spec.webrtc` wins whole, even `{}` (no ICE servers); a NetApp without one gets the default."""
    return own if own is not None else default


def webrtc_args(webrtc: WebRtcSpec | None) -> list[str]:
    return [] if webrtc is None else [arg for url in webrtc.ice_servers for arg in ("--ice-server", str(url))]


def webrtc_env(webrtc: WebRtcSpec | None) -> list[dict[str, Any]]:
    """A TURN server's username and credential from `turnSecret`, as `netapp serve` reads them."""
    if webrtc is None or not webrtc.turn_secret:
        return []
    return [
        {"name": env, "valueFrom": {"secretKeyRef": {"name": str(webrtc.turn_secret), "key": key}}}
        for env, key in zip((USERNAME_ENV, CREDENTIAL_ENV), TURN_SECRET_KEYS, strict=True)
    ]
