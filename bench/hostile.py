"""Hostile-input benchmark: the full-size attacks of issue 10, one after another, against a real `netapp serve` and
a real middleware, with a well-behaved robot streaming beside them (HTTP, ?wait=true, 320x240 JPEG at 10 FPS, in a
process of its own unless `--good-robot thread`).

    python -m bench.hostile --model ../shared/models/yolox_nano.onnx     # every attack (make bench-hostile)
    python -m bench.hostile --only jpeg-header,h264-flood                # some of them
    python -m bench.hostile --only h264-flood --flood-keyframes 2000 --flood-fps 200   # a fixed flood: runs compare

Prints, per attack: how many hostile requests were tried, whether the server survived, the good robot's longest
gap without a result and its p95 latency against its baseline (measured alone first), the server's peak RSS
during the attack, and how many frames or requests were lost (the good robot's frames without an answer, and
attacking requests that got no answer at all). Small versions of the same attacks run in
tests/netapp/server/test_hostile.py.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import requests
import socketio

from bench.hostile_cameras import CAMERA_ATTACKS, SECRETS, FailingCameras
from bench.hostile_rtp import RTP_ATTACKS
from bench.hostile_webrtc import WEBRTC_ATTACKS
from netapp.protocol import CONTROL_NAMESPACE, DATA_NAMESPACE, H264_EVENT
from netapp.serve_process import free_port, wait_http_ok
from tests.support.attacks import h264_keyframe_claiming, jpeg_claiming
from tests.support.images import make_jpeg
from tests.support.watch import GoodRobot, PeakRss, rss_bytes

ROOT = Path(__file__).resolve().parent.parent


@dataclass
class Outcome:
    tried: int
    lost: int = 0  # attacking requests that got no answer at all
    note: str = ""


class Target:
    """A `netapp serve` process on loopback."""

    def __init__(self, model: str, log: Path, cameras: FailingCameras | None = None) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.host = "127.0.0.1"
        self.model, self.log_path, self.cameras = model, log, cameras
        self._log = log.open("w")
        command = [sys.executable, "-m", "netapp", "serve", "--model", model, "--port", str(self.port)]
        first = free_port()  # a few UDP ports for the RTP attacks (the netapp skips one taken meanwhile)
        command += ["--rtp-ports", f"{first}-{min(first + 7, 65535)}"]
        for source in cameras.sources() if cameras is not None else ():  # issue 45's camera attacks
            command += ["--source", source]
        self.process = subprocess.Popen(command, stdout=self._log, stderr=subprocess.STDOUT)
        wait_http_ok(f"{self.url}/readyz", self.process, timeout_s=120)

    def alive(self) -> bool:
        try:
            return self.process.poll() is None and requests.get(f"{self.url}/healthz", timeout=5).ok
        except requests.RequestException:
            return False

    def close(self) -> None:
        self.process.terminate()
        self.process.wait(10)
        self._log.close()


def register(url: str) -> str | None:
    r = requests.post(f"{url}/register", json={}, timeout=10)
    return r.json()["session_id"] if r.status_code == 201 else None


def unregister(url: str, session_id: str | None) -> None:
    if session_id:
        requests.post(f"{url}/unregister", headers={"X-Session-Id": session_id}, timeout=10)


def post(url: str, session_id: str, data: bytes, timeout: float = 60, **headers: str) -> int:
    """The status of one ?wait=true frame; 0 when no answer came."""
    try:
        return requests.post(
            f"{url}/send_image?wait=true",
            data=data,
            headers={"X-Session-Id": session_id, "Content-Type": "image/jpeg", **headers},
            timeout=timeout,
        ).status_code
    except requests.RequestException:
        return 0


class Robot:
    """A raw Socket.IO robot, INIT done; counts the data_error events it gets."""

    def __init__(self, url: str) -> None:
        self.errors: list[dict] = []
        self.results = 0
        self.closed = threading.Event()
        self.sio = socketio.Client(reconnection=False)
        self.sio.on("data_error", self.errors.append, namespace=DATA_NAMESPACE)
        self.sio.on("results", lambda m: setattr(self, "results", self.results + 1), namespace=DATA_NAMESPACE)
        self.sio.on("disconnect", lambda *a: self.closed.set(), namespace=DATA_NAMESPACE)
        self.sio.connect(url, namespaces=[DATA_NAMESPACE, CONTROL_NAMESPACE], wait_timeout=10)
        self.init_ok, self.init_message = self.sio.call(
            "command", {"cmd_type": 1, "clear_queue": False, "data": {}}, namespace=CONTROL_NAMESPACE, timeout=10
        )

    def state(self) -> dict:
        _, text = self.sio.call("command", {"cmd_type": 3, "data": {}}, namespace=CONTROL_NAMESPACE, timeout=60)
        return json.loads(text)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.sio.disconnect()


def wait_until(condition: Callable[[], bool], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.05)
    return False


# -- the attacks ----------------------------------------------------------------------------------------------------


def jpeg_header(t: Target) -> Outcome:
    """A 629-byte JPEG claiming 65500x16000 (and 60000x60000), 50 times each over HTTP."""
    session = register(t.url)
    statuses = [post(t.url, session, jpeg_claiming(*size)) for size in [(65500, 16000), (60000, 60000)] * 50]
    unregister(t.url, session)
    return Outcome(len(statuses), statuses.count(0), f"statuses {sorted(set(statuses))}")


def jpeg_header_4_sessions(t: Target) -> Outcome:
    """The same from 4 sessions at once (30000x30000), 50 each."""
    sessions = [register(t.url) for _ in range(4)]
    data = jpeg_claiming(30000, 30000)
    with ThreadPoolExecutor(4) as pool:
        statuses = list(pool.map(lambda s: post(t.url, s, data), sessions * 50))
    for session in sessions:
        unregister(t.url, session)
    return Outcome(len(statuses), statuses.count(0), f"statuses {sorted(set(statuses))}")


def h264_sps(t: Target) -> Outcome:
    """H.264 whose SPS says 16000x16000 while the event declares 64x64, 20 keyframes, then the connection idles."""
    from netapp.client.h264 import H264Encoder

    packets, _ = H264Encoder(64, 64).encode(np.zeros((64, 64, 3), np.uint8))
    robot = Robot(t.url)
    for i in range(20):
        message = {"timestamp": i, "frame": h264_keyframe_claiming(packets, 16000, 16000), "width": 64, "height": 64}
        robot.sio.emit(H264_EVENT, message, namespace=DATA_NAMESPACE)
    answered = wait_until(lambda: len(robot.errors) >= 20, 30)
    reasons = sorted({e["reason"] for e in robot.errors})
    time.sleep(3)  # idle with the connection open: nothing may stay allocated
    robot.close()
    return Outcome(20, 0 if answered else 20 - len(robot.errors), f"errors {reasons}")


@dataclass
class Flood:
    """The H.264 flood's size: `seconds` as fast as the connection takes them (the default), or a fixed flood of
    `keyframes` at `fps`, so that runs compare."""

    seconds: float = 20.0
    keyframes: int = 0
    fps: float = 0.0


FLOOD = Flood()


def h264_flood(t: Target, width: int = 3840, height: int = 2160) -> Outcome:
    """A flood of 4K keyframes (the largest the default --max-pixels admits) from one robot; then 8192x8192 ones."""
    from netapp.client.h264 import H264Encoder

    encoder = H264Encoder(width, height, {"g": "1"})
    rng = np.random.default_rng(0)
    ramp = np.linspace(0, 255, width, dtype=np.uint8)[None, :, None]
    frames = [encoder.encode(ramp + rng.integers(0, 24, (height, width, 3), np.uint8))[0] for _ in range(3)]
    big = H264Encoder(64, 64).encode(np.zeros((64, 64, 3), np.uint8))[0]
    robot = Robot(t.url)
    start = time.monotonic()
    sent, deadline = 0, start + (FLOOD.keyframes / FLOOD.fps * 3 if FLOOD.keyframes else FLOOD.seconds)
    while time.monotonic() < deadline and (not FLOOD.keyframes or sent < FLOOD.keyframes):
        if FLOOD.keyframes:  # the fixed flood: keyframe `sent` leaves at sent / fps
            time.sleep(max(0.0, start + sent / FLOOD.fps - time.monotonic()))
        message = {"timestamp": sent, "frame": frames[sent % 3], "width": width, "height": height}
        robot.sio.emit(H264_EVENT, message, namespace=DATA_NAMESPACE)
        sent += 1
        while robot.sio.eio.queue.qsize() > 2 and time.monotonic() < deadline:
            time.sleep(0.001)  # as fast as the connection takes them, not into this process's memory
    for i in range(50):  # 8192x8192 keyframes, as in the issue: refused at once from their SPS
        message = {"timestamp": sent + i, "frame": h264_keyframe_claiming(big, 8192, 8192), "width": 64, "height": 64}
        robot.sio.emit(H264_EVENT, message, namespace=DATA_NAMESPACE)
    took = time.monotonic() - start
    total = sent + 50
    accounted = wait_until(
        lambda: (s := robot.state())["processed"] + s["dropped"] + s["rejected"] >= total, 120
    )  # every frame of the flood has its fate counted
    state = robot.state()
    robot.close()
    fates = state["processed"] + state["dropped"] + state["rejected"]
    note = f"{sent} 4K keyframes in {took:.1f} s + 50 8K: processed {state['processed']}, dropped "
    note += f"{state['dropped']}, refused "
    return Outcome(total, 0 if accounted else total - fates, note + str(state["rejected"]))


def socketio_attachments(t: Target) -> Outcome:
    """A packet announcing 1,000,000 binary attachments, then 250 x 8 MB; and one announcing 4, then 3 x 9 MB."""
    refused = 0
    for header, chunks, size in (("1000000", 250, 8 * 2**20), ("4", 3, 9 * 2**20)):
        robot = Robot(t.url)
        placeholders = ",".join(f'{{"_placeholder":true,"num":{i}}}' for i in range(min(int(header), 4)))
        robot.sio.eio.send(f'5{header}-/data,["image",[{placeholders}]]')
        chunk = b"\0" * size
        for _ in range(chunks):
            if robot.closed.is_set():
                break
            with contextlib.suppress(Exception):
                robot.sio.eio.send(chunk)
        refused += wait_until(robot.closed.is_set, 30)
        robot.close()
    return Outcome(2, 2 - refused, f"{refused} of 2 connections refused and closed")


def register_flood(t: Target) -> Outcome:
    """/register 300 times with 1 MB args, then 20,000 times with none."""
    args = {"x": "y" * 2**20}
    local = threading.local()

    def send(body: dict) -> requests.Response:
        if not hasattr(local, "http"):
            local.http = requests.Session()  # keep-alive: 20,000 requests, not 20,000 connections
        return local.http.post(f"{t.url}/register", json=body, timeout=60)

    with ThreadPoolExecutor(16) as pool:
        big = [r.status_code for r in pool.map(lambda _: send(args), range(300))]
        empty = list(pool.map(lambda _: send({}), range(20_000)))
    opened = [r.json()["session_id"] for r in empty if r.status_code == 201]
    for session in opened:
        unregister(t.url, session)
    statuses = sorted({*big, *(r.status_code for r in empty)})
    return Outcome(20_300, 0, f"statuses {statuses}; {len(opened)} sessions opened (cap), the rest 503")


def half_open(t: Target) -> Outcome:
    """200 half-sent requests (headers, or headers and part of a body) and 1,500 idle connections."""
    idle = [socket.create_connection((t.host, t.port), timeout=30) for _ in range(1500)]
    half = [socket.create_connection((t.host, t.port), timeout=30) for _ in range(200)]
    session = register(t.url)
    for i, sock in enumerate(half):
        head = f"POST /send_image HTTP/1.1\r\nHost: x\r\nX-Session-Id: {session}\r\nContent-Type: image/jpeg\r\n"
        sock.sendall(head.encode() + (b"Content-Length: 100000\r\n\r\n" + b"\xff\xd8" * 50 if i % 2 else b""))
    for sock in half[:20]:  # aborted uploads: one log line each, no traceback
        sock.close()
    closed = 0
    for sock in idle + half[20:]:
        with contextlib.suppress(OSError):
            while sock.recv(65536):
                pass
            closed += 1
        sock.close()
    unregister(t.url, session)
    return Outcome(1700, 1680 - closed, f"{closed} of 1680 left open were closed by the server")


def wait_flood(t: Target, robots: int = 1) -> Outcome:
    """500 concurrent ?wait=true requests from one robot (one session)."""
    sessions = [register(t.url) for _ in range(robots)]
    jpeg = make_jpeg(640, 480)
    with ThreadPoolExecutor(500) as pool:
        statuses = list(pool.map(lambda i: post(t.url, sessions[i % robots], jpeg), range(500)))
    for session in sessions:
        unregister(t.url, session)
    counts = {s: statuses.count(s) for s in sorted(set(statuses))}
    return Outcome(500, statuses.count(0), f"statuses {counts}")


def bad_headers(t: Target) -> Outcome:
    """Malformed X-Timestamp (--5, superscript two, 4,301 digits) 100 times each, and Socket.IO events with 0 or
    2 arguments."""
    session = register(t.url)
    jpeg = make_jpeg()
    statuses = [post(t.url, session, jpeg, **{"X-Timestamp": v}) for v in ["--5", "\xb2", "1" * 4301] * 100]
    unregister(t.url, session)
    robot = Robot(t.url)
    for _ in range(50):
        robot.sio.emit("image", (), namespace=DATA_NAMESPACE)
        robot.sio.emit("image", ({"timestamp": 1, "frame": jpeg}, 2), namespace=DATA_NAMESPACE)
    answered = wait_until(lambda: len(robot.errors) >= 100, 30)
    robot.close()
    lost = statuses.count(0) + (0 if answered else 100 - len(robot.errors))
    return Outcome(400, lost, f"statuses {sorted(set(statuses))}; {len(robot.errors)} of 100 events got data_error")


def _outcome(attack: Callable[[Target], tuple[int, int, str]]) -> Callable[[Target], Outcome]:
    return lambda t: Outcome(*attack(t))


NETAPP_ATTACKS: dict[str, Callable[[Target], Outcome]] = {
    "jpeg-header": jpeg_header,
    "jpeg-header-4-sessions": jpeg_header_4_sessions,
    "h264-sps": h264_sps,
    "h264-flood": h264_flood,
    "socketio-attachments": socketio_attachments,
    "register-flood": register_flood,
    "half-open": half_open,
    "wait-flood": wait_flood,
    # 10 sessions are 10 robots: each gets its turn (round robin), the good robot 1/11 of the inferences
    "wait-flood-10-sessions": lambda t: wait_flood(t, robots=10),
    "bad-headers": bad_headers,
    # issue 35: RTP pushed over UDP (bench/hostile_rtp.py)
    **{name: _outcome(attack) for name, attack in RTP_ATTACKS.items()},
    # issue 35: WebRTC offers (bench/hostile_webrtc.py)
    **{name: _outcome(attack) for name, attack in WEBRTC_ATTACKS.items()},
    # issue 45: cameras, WebRTC tracks, offers and candidates, RTP sequence jumps, watchers (bench/hostile_cameras.py)
    **{name: _outcome(attack) for name, attack in CAMERA_ATTACKS.items()},
}


# -- the middleware ---------------------------------------------------------------------------------------------------


@contextlib.contextmanager
def middleware() -> Iterator[tuple[str, subprocess.Popen]]:
    from netapp_middleware.auth import hash_secret

    with tempfile.TemporaryDirectory() as tmp:
        robots = Path(tmp) / "robots.yaml"
        robots.write_text(f"robots:\n  robot-1: '{hash_secret('secret-one')}'\n")
        key = Path(tmp) / "key"
        key.write_text("k" * 48)
        port = free_port()
        command = [sys.executable, "-m", "netapp", "middleware", "--port", str(port), "--robots-file", str(robots)]
        command += ["--token-key-file", str(key)]
        process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
        url = f"http://127.0.0.1:{port}"
        try:
            wait_http_ok(f"{url}/healthz", process, timeout_s=60)
            yield url, process
        finally:
            process.terminate()
            process.wait(10)


def login_flood(url: str, concurrency: int) -> tuple[Outcome, float]:
    """`concurrency` wrong-secret logins at once, 5 rounds; returns the outcome and /healthz's worst latency."""
    worst = [0.0]
    stop = threading.Event()

    def probe() -> None:
        while not stop.is_set():
            start = time.monotonic()
            with contextlib.suppress(requests.RequestException):
                requests.get(f"{url}/healthz", timeout=10)
            worst[0] = max(worst[0], time.monotonic() - start)
            time.sleep(0.05)

    prober = threading.Thread(target=probe, daemon=True)
    prober.start()

    def login(i: int) -> int:
        body = {"robot_id": f"robot-{i % 3}", "secret": "wrong"}
        try:
            return requests.post(f"{url}/auth/token", json=body, timeout=60).status_code
        except requests.RequestException:
            return 0

    with ThreadPoolExecutor(concurrency) as pool:
        statuses = list(pool.map(login, range(concurrency * 5)))
    stop.set()
    prober.join()
    counts = {s: statuses.count(s) for s in sorted(set(statuses))}
    return Outcome(len(statuses), statuses.count(0), f"statuses {counts}"), worst[0]


# -- the run ----------------------------------------------------------------------------------------------------------


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default=str(ROOT.parent / "shared" / "models" / "yolox_nano.onnx"))
    parser.add_argument("--only", help="comma-separated attacks (default: all): " + ", ".join(NETAPP_ATTACKS))
    parser.add_argument("--baseline", type=float, default=8.0, help="seconds of the good robot alone (8)")
    parser.add_argument(
        "--good-robot",
        choices=("process", "thread"),
        default="process",
        help="where the good robot runs: its own process (a robot elsewhere; the default), or a thread of the "
        "attacking process, whose threads then delay it too (this bench before issue 22)",
    )
    parser.add_argument("--flood-keyframes", type=int, default=0, help="the H.264 flood: this many keyframes")
    parser.add_argument("--flood-fps", type=float, default=75.0, help="... at this rate (75)")
    args = parser.parse_args()
    FLOOD.keyframes, FLOOD.fps = args.flood_keyframes, args.flood_fps
    chosen = args.only.split(",") if args.only else list(NETAPP_ATTACKS) + ["middleware-logins"]
    rows = []
    cameras = FailingCameras() if any(n in CAMERA_ATTACKS for n in chosen) else None
    with tempfile.TemporaryDirectory() as tmp:
        target = Target(args.model, Path(tmp) / "netapp.log", cameras)
        try:
            with GoodRobot(target.url, period_s=0.1, own_process=args.good_robot == "process") as good:
                good.wait_for_results(5)
                start = time.monotonic()
                time.sleep(args.baseline)
                baseline = good.window(start)
                p95, gap = baseline.p95_latency_s * 1000, baseline.longest_gap_s
                print(f"baseline: p95 {p95:.0f} ms, longest gap {gap:.2f} s")
                for name in (n for n in chosen if n in NETAPP_ATTACKS):
                    start = time.monotonic()
                    with PeakRss(target.process.pid) as rss:
                        outcome = NETAPP_ATTACKS[name](target)
                        time.sleep(1.0)  # the good robot's next results, after the attack
                    window = good.window(start)
                    survived = target.alive()
                    rows.append((name, outcome, survived, window, rss.peak, baseline, time.monotonic() - start))
                    after = rss_bytes(target.process.pid) / 2**20  # what the allocator kept
                    print(f"{name}: {outcome.note}; netapp RSS 1 s after: {after:.0f} MiB", flush=True)
            log = (Path(tmp) / "netapp.log").read_text()
            print(f"netapp log: {log.count('Traceback')} tracebacks, {log.count('went away')} aborted-upload lines")
            if cameras is not None:
                print(f"netapp log: the cameras' passwords {sum(log.count(p) for p in SECRETS)} times")
        finally:
            target.close()
            if cameras is not None:
                cameras.close()
    print()
    print(
        "| attack | tried | survived | good robot: longest gap / p95 (alone, ratio) | good robot's results (share) "
        "| netapp peak RSS | lost |"
    )
    print("|---|---|---|---|---|---|---|")
    for name, outcome, survived, window, peak, base, seconds in rows:
        lost = outcome.lost + window.failures
        share = window.results / max(1.0, seconds / 0.1)  # the good robot sends every 0.1 s
        print(
            f"| {name} | {outcome.tried} | {'yes' if survived else 'NO'} | {window.longest_gap_s:.2f} s / "
            f"{window.p95_latency_s * 1000:.0f} ms ({base.p95_latency_s * 1000:.0f} ms, "
            f"{window.p95_latency_s / base.p95_latency_s:.1f}x) | {window.results} ({share:.0%}) | "
            f"{peak / 2**20:.0f} MiB | {lost} |"
        )
    if "middleware-logins" in chosen:
        print()
        print("| middleware attack | tried | survived | worst /healthz | middleware peak RSS | lost |")
        print("|---|---|---|---|---|---|")
        with middleware() as (url, process):
            for concurrency in (16, 100):
                with PeakRss(process.pid) as rss:
                    outcome, worst = login_flood(url, concurrency)
                alive = process.poll() is None and requests.get(f"{url}/healthz", timeout=5).ok
                print(
                    f"| {concurrency} concurrent wrong-secret logins x5 | {outcome.tried} | {'yes' if alive else 'NO'}"
                    f" | {worst * 1000:.0f} ms | {rss.peak / 2**20:.0f} MiB | {outcome.lost} |"
                )
                print(f"  {outcome.note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
