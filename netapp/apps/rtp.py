"""`netapp rtp open URL`: open an RTP session on a netapp over HTTP (`POST /register` with `rtp`, as
docs/cameras.md#rtp-push writes it) and print the `gst-launch-1.0` line that pushes H.264 to it, with its port and
SSRC: a GStreamer sender needs no WebSocket client. Its results are polled with `GET /results`; the session closes
with `POST /unregister`, or when idle (the netapp's --session-ttl)."""

from __future__ import annotations

import argparse
import json
import shlex
from typing import Any
from urllib.parse import urlsplit

TIMEOUT_S = 10.0
DEFAULT_SOURCE = "videotestsrc is-live=true ! video/x-raw,width=1280,height=720,framerate=10/1"
ENCODER = "x264enc tune=zerolatency speed-preset=ultrafast key-int-max=30"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="rtp_command", metavar="ACTION", required=True)
    opened = sub.add_parser("open", help="open an RTP session and print the gst-launch-1.0 line that sends to it")
    opened.add_argument("url", help="the netapp's URL, e.g. http://127.0.0.1:5896 (started with --rtp-ports)")
    opened.add_argument("--robot-id", help="the robot's id (its results and metrics carry it)")
    opened.add_argument("--token", help="the netapp's token, if it needs one (or NETAPP_TOKEN)")
    opened.add_argument(
        "--address", help="the sender's IP address, when it is not this machine's (the netapp takes RTP from it only)"
    )
    opened.add_argument("--payload-type", type=int, default=96, help="RTP payload type, 96 to 127 (default 96)")
    opened.add_argument(
        "--source",
        default=DEFAULT_SOURCE,
        help="the GStreamer elements before the encoder (default: a test picture; a camera is v4l2src, "
        "nvarguscamerasrc, ...)",
    )
    opened.add_argument("--json", action="store_true", help="print /register's answer with the line as gst_launch")


def gst_launch(host: str, rtp: dict[str, Any], source: str = DEFAULT_SOURCE) -> str:
    """The sender's pipeline for an RTP session's answer (pure): `source`, x264 at zero latency, RFC 6184 packets
    with the session's payload type and SSRC, to the netapp's port."""
    return (
        f"gst-launch-1.0 {source} ! {ENCODER} ! rtph264pay config-interval=1 pt={int(rtp['payload_type'])} "
        f"ssrc={int(rtp['ssrc'])} ! udpsink host={shlex.quote(host)} port={int(rtp['port'])}"
    )


def register(url: str, body: dict[str, Any], token: str | None) -> dict[str, Any]:
    """POST /register's answer; RuntimeError, one line, when the netapp refuses or cannot be reached."""
    import requests

    headers = {"Authorization": f"Bearer {token}"} if token else {}
    try:
        answer = requests.post(url + "/register", json=body, headers=headers, timeout=TIMEOUT_S)
    except requests.RequestException as exc:
        raise RuntimeError(f"cannot reach {url}: {exc.__class__.__name__} (is the netapp running there?)") from None
    if answer.status_code != 201:
        try:
            said = answer.json().get("error")
        except ValueError:
            said = None
        raise RuntimeError(f"{url} refused the session ({answer.status_code}): {said or answer.text[:200]}")
    return answer.json()


def run(args: argparse.Namespace) -> int:
    import logging
    import os

    import requests

    from netapp.protocol import TOKEN_ENV

    log = logging.getLogger("netapp.rtp")
    url = args.url.rstrip("/")
    token = args.token or os.environ.get(TOKEN_ENV) or None
    rtp: dict[str, Any] = {"payload_type": args.payload_type}
    if args.address:
        rtp["address"] = args.address
    try:
        opened = register(url, {"robot_id": args.robot_id, "args": {"rtp": rtp}}, token)
    except RuntimeError as exc:
        log.error("%s", exc)
        return 1
    session = {"X-Session-Id": opened["session_id"]}
    if not opened.get("rtp"):
        requests.post(url + "/unregister", headers=session, timeout=TIMEOUT_S)
        log.error("%s takes no RTP: start it with --rtp-ports, e.g. --rtp-ports 50000-50099", url)
        return 1
    line = gst_launch(urlsplit(url).hostname or "127.0.0.1", opened["rtp"], args.source)
    if args.json:
        print(json.dumps({**opened, "gst_launch": line}))
        return 0
    print(line)
    sid = opened["session_id"]
    log.info(
        "session open: RTP port %d, SSRC %d; its results: curl -H 'X-Session-Id: %s' %s/results; close it: "
        "curl -X POST -H 'X-Session-Id: %s' %s/unregister (an idle session closes by itself)",
        opened["rtp"]["port"], opened["rtp"]["ssrc"], sid, url, sid, url,
    )  # fmt: skip
    return 0
