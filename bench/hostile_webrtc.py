"""bench/hostile.py's WebRTC attacks (issue 35): offers of absurd sizes, and a flood of offers that never connect,
beside the good robot. What the netapp counted is read from its /metrics (`netapp_webrtc_refused_total{reason}`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import requests

REFUSED = "netapp_webrtc_refused_total"
HEAD = "v=0\r\no=- 1 2 IN IP4 127.0.0.1\r\ns=-\r\nt=0 0\r\n"


def refusals(url: str) -> dict[str, float]:
    rows = requests.get(f"{url}/metrics", timeout=10).text.splitlines()
    return {row.rsplit(" ", 1)[0]: float(row.rsplit(" ", 1)[1]) for row in rows if row.startswith(REFUSED)}


def counted_since(url: str, before: dict[str, float]) -> str:
    now = refusals(url)
    counts = {k.split("=")[-1].strip('"}'): int(v - before.get(k, 0.0)) for k, v in now.items()}
    return ", ".join(f"{k} {v}" for k, v in sorted(counts.items()) if v)


def absurd_offers() -> list[bytes]:
    """Bodies of absurd sizes: 16 MB of SDP, 1 MB of one line, 100,000 m-lines, 10,000 tiny lines of garbage, a
    body that is no JSON, JSON nested 100,000 deep."""
    return [
        b'{"type": "offer", "sdp": "' + b"v=0\\r\\n" + b"a" * (16 << 20) + b'"}',
        ('{"type": "offer", "sdp": "' + HEAD.replace("\r\n", "\\r\\n") + "a=" + "x" * (1 << 20) + '"}').encode(),
        (
            '{"type": "offer", "sdp": "'
            + (HEAD + "m=video 9 RTP/AVP 96\r\n" * 100_000).replace("\r\n", "\\r\\n")
            + '"}'
        ).encode(),
        (
            '{"type": "offer", "sdp": "' + (HEAD + "m=video 9 RTP/AVP 96\r\n" * 300).replace("\r\n", "\\r\\n") + '"}'
        ).encode(),
        ('{"type": "offer", "sdp": "' + (HEAD + "\x01=\x02\r\n" * 1000).replace("\r\n", "\\r\\n") + '"}').encode(),
        b"\x00\xff" * 4096,
        b"[" * 100_000 + b"]" * 100_000,
    ]


def webrtc_absurd_sdp(t: Any, rounds: int = 10) -> tuple[int, int, str]:
    """POST /webrtc/offer with each absurd body, `rounds` times; each must be refused with a 4xx and counted."""
    before = refusals(t.url)
    statuses: dict[int, int] = {}
    lost = 0
    for _ in range(rounds):
        for body in absurd_offers():
            try:
                status = requests.post(f"{t.url}/webrtc/offer", data=body, timeout=30).status_code
            except requests.RequestException:  # the netapp may close a connection it refused mid-upload
                status = 0
            statuses[status] = statuses.get(status, 0) + 1
            lost += status == 0 or status >= 500
    tried = rounds * len(absurd_offers())
    return tried, lost, f"statuses {dict(sorted(statuses.items()))}; counted: {counted_since(t.url, before)}"


WEBRTC_ATTACKS: dict[str, Callable[[Any], tuple[int, int, str]]] = {
    "webrtc-absurd-sdp": webrtc_absurd_sdp,
}
