"""bench/hostile.py's attacks of issue 45: the cameras the netapp pulls (credentials in FFmpeg's errors, URLs it cannot
pull, an 8K stream), WebRTC (an 8K track, offers that could never connect, candidates elsewhere), RTP sequence jumps
and watchers that hold every slot, each beside the good robot. What the netapp counted is read from its /metrics;
every output is searched for the cameras' passwords."""

from __future__ import annotations

import contextlib
import json
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import requests
from websockets.sync.client import connect

from bench.hostile_rtp import bound_session, rtp_metrics
from netapp.framing import frames_url
from netapp.protocol import CommandType
from netapp.rtp.packet import build
from netapp.serve_process import free_port
from tests.support.fake_cameras import HostileCamera, RefusingCamera
from tests.support.rtp_attacks import send_all
from tests.support.sdp_attacks import BROKEN, foreign_candidates
from tests.support.watcher import Watcher

SECRETS = ("S3cr3tPw1", "p%40ss%2Fw0rd", "p@ss/w0rd")
BIG = "big"  # the camera that appears at 7680x4320 during its row
BAD_URLS = {  # what a hand may write: each must be refused at start, exit 2, one line, no password
    "a '/' in the password": "rtsp://admin:S3cr3t/Pw1@127.0.0.1:554/cam",
    "a '?' in the password": "rtsp://admin:S3cr3t?Pw1@127.0.0.1:554/cam",
    "a '#' in the password": "rtsp://admin:S3cr3t#Pw1@127.0.0.1:554/cam",
    "two '@'": "rtsp://admin:S3cr3t@Pw1@127.0.0.1:554/cam",
    "a space": "rtsp://admin:S3cr3t Pw1@127.0.0.1:554/cam",
    "port 99999": "rtsp://admin:S3cr3tPw1@127.0.0.1:99999/cam",
}


class FailingCameras:
    """Cameras on loopback that fail every way FFmpeg can fail, each named with a password, plain and encoded; and
    the port where the 8K camera appears later. Started before the netapp: `sources()` are its --source values."""

    def __init__(self) -> None:
        self.refusing = RefusingCamera()
        self.junk = HostileCamera(b"HTTP/1.0 200 OK\r\n\r\n" + b"\xff" * 999)
        self.silent = HostileCamera()
        self.big_port = free_port()
        ports = {"refusing": self.refusing.port, "junk": self.junk.port, "silent": self.silent.port}
        ports["closed"] = free_port()
        self.names = [f"{name}{i}" for name in ports for i in range(2)]
        self._urls = [f"rtsp://admin:{pw}@127.0.0.1:{p}/cam" for p in ports.values() for pw in SECRETS[:2]]

    def sources(self) -> list[str]:
        named = [f"{n}={u}" for n, u in zip(self.names, self._urls, strict=True)]
        return [*named, f"{BIG}=rtsp://127.0.0.1:{self.big_port}/cam#transport=tcp"]

    def close(self) -> None:
        for camera in (self.refusing, self.junk, self.silent):
            camera.close()


def metrics_text(url: str) -> str:
    return requests.get(f"{url}/metrics", timeout=10).text


def counter(url: str, prefix: str) -> float:
    """The sum of every series whose line starts with `prefix` (a name, or a name and labels)."""
    return sum(float(line.rsplit(" ", 1)[1]) for line in metrics_text(url).splitlines() if line.startswith(prefix))


def secrets_in(texts: list[str]) -> int:
    return sum(text.count(secret) for text in texts for secret in SECRETS)


def outputs(t: Any) -> list[str]:
    """Everything the netapp said: its log, /metrics, the live page and its API."""
    pages = [requests.get(t.url + path, timeout=10).text for path in ("/metrics", "/ui", "/ui/api/robots")]
    return [t.log_path.read_text(errors="replace"), *pages]


def wait_for(condition: Callable[[], bool], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.2)  # polling the netapp's log and metrics
    return False


def camera_secrets(t: Any) -> tuple[int, int, str]:
    """Eight cameras with passwords that fail (401, refused, nonsense, silence): told in the log, no password."""
    names = t.cameras.names

    def told() -> int:
        log = t.log_path.read_text(errors="replace")
        return sum(f"camera {n}: unreachable" in log for n in names)

    wait_for(lambda: told() == len(names), 30)
    down = sum(counter(t.url, f'netapp_source_up{{source="{n}"}}') == 0 for n in names)
    found = secrets_in(outputs(t))
    return len(names), len(names) - told(), f"{told()} of {len(names)} told unreachable, {down} down; secrets: {found}"


def camera_bad_urls(t: Any) -> tuple[int, int, str]:
    """`netapp serve --source` with URLs FFmpeg would read otherwise: exit 2 at start, one line, no password."""
    refused, texts = 0, []
    for url in BAD_URLS.values():
        command = [sys.executable, "-m", "netapp", "serve", "--model", t.model, "--source", f"door={url}"]
        run = subprocess.run(command, capture_output=True, text=True, timeout=120)
        lines = [line for line in (run.stdout + run.stderr).splitlines() if line.strip()]
        refused += run.returncode == 2 and len(lines) <= 2
        texts += [run.stdout, run.stderr]
    found = sum(text.count("S3cr3t") for text in texts)
    return len(BAD_URLS), len(BAD_URLS) - refused, f"{refused} exit 2 in one line; secrets: {found}"


def camera_8k(t: Any) -> tuple[int, int, str]:
    """A camera appears at 7680x4320 (1 fps): refused at its stream's size, nothing decoded at it."""
    from tests.support.rtsp_camera import RtspCamera, gstreamer_problem

    problem = gstreamer_problem()
    if problem:
        return 0, 0, f"skipped: {problem}"
    line = f"(camera {BIG}'s stream of 7680x4320"
    with RtspCamera(t.cameras.big_port, 7680, 4320, 1):
        refused = wait_for(lambda: line in t.log_path.read_text(errors="replace"), 60)
    decoded = counter(t.url, f'netapp_source_pictures_decoded_total{{source="{BIG}"}}')
    return 1, 0 if refused else 1, f"refused: {'yes' if refused else 'NO'} ({line}...); {decoded:.0f} pictures decoded"


def webrtc_8k(t: Any, pictures: int = 10) -> tuple[int, int, str]:
    """One WebRTC peer sends 7680x4320 pictures: each refused (too_many_pixels), none decoded."""
    from netapp.client.webrtc import WebRtcClient

    key = 'netapp_frames_rejected_total{reason="too_many_pixels",transport="webrtc"}'
    before = counter(t.url, key)
    client = WebRtcClient(t.url, robot_id="8k", ice_addresses=("127.0.0.1",))
    client.connect()
    picture = np.zeros((4320, 7680, 3), np.uint8)
    try:
        for _ in range(pictures):
            client.send(picture)
            time.sleep(0.5)  # the client's encoder (8K VP8) is slow: one at a time
        wait_for(lambda: client.stats.errors >= 1, 10)
    finally:
        client.close()
    refused = counter(t.url, key) - before
    stats = client.stats
    return (
        pictures,
        0,
        f"robot got {stats.errors} errors, {stats.results} results; {refused:.0f} too_many_pixels counted",
    )


def webrtc_never_connect(t: Any, rounds: int = 10) -> tuple[int, int, str]:
    """Seven kinds of offers aiortc answered and never connected, from a real offer: refused at once as bad_sdp."""
    from netapp.client.webrtc import WebRtcClient

    client = WebRtcClient(t.url, ice_addresses=("127.0.0.1",))
    client._thread.start()
    sdp = client._run(client._offer())
    before = counter(t.url, 'netapp_webrtc_refused_total{reason="bad_sdp"}')
    statuses: dict[int, int] = {}
    slowest = 0.0
    try:
        for _ in range(rounds):
            for change in BROKEN.values():
                started = time.monotonic()
                status = requests.post(f"{t.url}/webrtc/offer", json={"type": "offer", "sdp": change(sdp)}, timeout=30)
                slowest = max(slowest, time.monotonic() - started)
                statuses[status.status_code] = statuses.get(status.status_code, 0) + 1
    finally:
        client.close()
    counted = counter(t.url, 'netapp_webrtc_refused_total{reason="bad_sdp"}') - before
    peers = counter(t.url, "netapp_webrtc_peers ")
    tried = rounds * len(BROKEN)
    note = (
        f"statuses {statuses}, slowest {slowest * 1000:.0f} ms; {counted:.0f} bad_sdp counted; {peers:.0f} peers held"
    )
    return tried, sum(n for s, n in statuses.items() if s != 400), note


def webrtc_candidates(t: Any, offers: int = 4, each: int = 25) -> tuple[int, int, str]:
    """Offers naming 25 candidates elsewhere each (a real offer's own besides): none of them is ever checked."""
    from netapp.client.webrtc import WebRtcClient

    key = "netapp_webrtc_candidates_dropped_total"
    before = counter(t.url, key)
    statuses: dict[int, int] = {}
    for _ in range(offers):
        client = WebRtcClient(t.url, ice_addresses=("127.0.0.1",))
        client._thread.start()
        sdp = client._run(client._offer()) + foreign_candidates(each)
        status = requests.post(f"{t.url}/webrtc/offer", json={"type": "offer", "sdp": sdp}, timeout=30).status_code
        statuses[status] = statuses.get(status, 0) + 1
        client.close()
    dropped = counter(t.url, key) - before
    return offers * each, 0, f"statuses {statuses}; {dropped:.0f} of {offers * each} candidates dropped (never checked)"


def rtp_sequence_jumps(t: Any, seconds: float = 10.0, rate: float = 2000.0) -> tuple[int, int, str]:
    """A robot's own RTP with sequence numbers 32,000 ahead each packet, 2,000 a second (within its packet gate)."""
    robot, sock, target, ssrc = bound_session(t.url)
    before = rtp_metrics(t.url)
    before_restarts = counter(t.url, "netapp_rtp_restarts_total")
    sent, sequence, start = 0, 0, time.monotonic()
    while time.monotonic() - start < seconds:
        burst = []
        for _ in range(int(rate / 100)):
            sequence = (sequence + 32_000) & 0xFFFF
            burst.append(build(b"\x41\x9a", payload_type=96, sequence=sequence, timestamp=sent, ssrc=ssrc, marker=True))
            sent += 1
        send_all(burst, target, sock)
        time.sleep(0.01)  # 100 bursts a second
    time.sleep(1.0)
    read = rtp_metrics(t.url).get("netapp_rtp_packets_total", 0) - before.get("netapp_rtp_packets_total", 0)
    restarts = counter(t.url, "netapp_rtp_restarts_total") - before_restarts
    sock.close()
    robot.close()
    return sent, 0, f"{read:.0f} read; {restarts:.0f} restarts counted (each O(1))"


def watch_hold(t: Any, held: int = 16, real: int = 5) -> tuple[int, int, str]:
    """16 WATCH connections from one address (127.0.0.2) that never read a result; then 5 real `netapp watch`."""
    connections, acks = [], {}
    for _ in range(held):
        sock = socket.socket()
        sock.bind(("127.0.0.2", 0))
        sock.connect(("127.0.0.1", int(t.url.rsplit(":", 1)[1])))
        ws = connect(frames_url(t.url), sock=sock, open_timeout=10)
        ws.send(json.dumps({"id": 1, "cmd_type": int(CommandType.WATCH), "data": {"source": BIG}}))
        ack = json.loads(ws.recv(timeout=10))
        while ack.get("event") != "ack":
            ack = json.loads(ws.recv(timeout=10))
        reason = "ok" if ack.get("ok") else str(ack.get("reason"))
        acks[reason] = acks.get(reason, 0) + 1
        connections.append(ws)
    with contextlib.ExitStack() as stack:
        watchers = [stack.enter_context(Watcher(t.url, BIG)) for _ in range(real)]
        time.sleep(3.0)
        refused = sum(w.error is not None for w in watchers)
    for ws in connections:
        ws.close()
    counted = counter(t.url, "netapp_source_watchers_refused_total")
    note = (
        f"held connections: {acks}; real watchers refused: {refused} of {real}; watchers refused in all: {counted:.0f}"
    )
    return held + real, refused, note


CAMERA_ATTACKS: dict[str, Callable[[Any], tuple[int, int, str]]] = {
    "camera-secrets": camera_secrets,
    "camera-bad-urls": camera_bad_urls,
    "camera-8k": camera_8k,
    "webrtc-8k": webrtc_8k,
    "webrtc-never-connect": webrtc_never_connect,
    "webrtc-candidates": webrtc_candidates,
    "rtp-sequence-jumps": rtp_sequence_jumps,
    "watch-hold": watch_hold,
}
