"""What forwarding to a session's owner costs: the same requests to the owner and through another replica.

    python -m bench.forwarding                   # 2 replicas of `netapp serve` (a tiny model: the hop, not inference)
    python -m bench.forwarding --rounds 10 --per-round 50
    python -m bench.forwarding --tls             # replicas serving HTTPS, forwarding over TLS (HTTP rows only)

Rows, each measured both ways, interleaved round by round (the machine is shared and noisy):
- HTTP `GET /results` (a polling robot's poll) and `POST /send_image` of a 640x480 JPEG for polling: straight to
  the owner, or landing on the other replica, which forwards it (httpx);
- HTTP `POST /send_image?wait=true`: the owner or the other replica, which processes it itself (no hop);
- a Socket.IO frame (JPEG event -> results event): its WebSocket on the owner, or on the other replica, which
  relays it (`websockets`). Both go through one HAProxy in HTTP mode, routing the upgrade by a rule, so the only
  difference is the relay.
With `--tls` the replicas serve HTTPS with certificates from a CA made here and verify each other against it
(docs/security.md#tls-between-replicas); the Socket.IO rows, which need HAProxy to speak TLS, are left out.
Prints a Markdown table (p50, p95, extra p50 over direct) and writes it to results/forwarding-<time>.md.
"""

from __future__ import annotations

import argparse
import os
import queue
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import requests
import socketio

from bench.robot import robot_jpeg
from netapp.client.stats import percentile
from tests.support.certificates import certificate_authority
from tests.support.haproxy import HAProxy
from tests.support.onnx_models import TINY_BOX, yolox_model
from tests.support.replicas import Replicas

ROOT = Path(__file__).resolve().parent.parent


def frame_jpeg() -> bytes:
    """A 640x480 JPEG about the size of a camera frame (textured, so it does not compress to nothing)."""
    rng = np.random.default_rng(0)
    image = cv2.resize(rng.integers(0, 255, (60, 80, 3), np.uint8), (640, 480), interpolation=cv2.INTER_CUBIC)
    return robot_jpeg(image)


def routing_config(polling: str, websocket: str):
    """HAProxy in HTTP mode: Engine.IO polling to one replica, the WebSocket upgrade to another."""

    def config(port: int) -> str:
        def server(url: str) -> str:
            return url.removeprefix("http://")

        return (
            "defaults\n    mode http\n    timeout connect 2s\n    timeout client 60s\n    timeout server 60s\n"
            "    timeout tunnel 1h\n"
            f"frontend f\n    bind 127.0.0.1:{port}\n    acl ws urlp(transport) websocket\n"
            "    use_backend websocket if ws\n    default_backend polling\n"
            f"backend polling\n    server p {server(polling)}\n"
            f"backend websocket\n    server w {server(websocket)}\n"
        )

    return config


class SocketIORobot:
    """python-socketio (polling first, then WebSocket), INIT, one frame at a time."""

    def __init__(self, url: str) -> None:
        self.results: queue.Queue = queue.Queue()
        self.sio = socketio.Client(reconnection=False)
        self.sio.on("results", self.results.put, namespace="/data")
        self.sio.connect(url, namespaces=["/data", "/control"], wait_timeout=10)
        deadline = time.monotonic() + 10
        while self.sio.transport() != "websocket":  # the upgrade is what the relay carries
            assert time.monotonic() < deadline, "no WebSocket upgrade"
            time.sleep(0.01)
        ok, message = self.sio.call("command", {"cmd_type": 1, "data": {}}, namespace="/control", timeout=10)
        assert ok, message

    def round_trip_ms(self, jpeg: bytes, timestamp: int) -> float:
        start = time.perf_counter()
        self.sio.emit("image", {"timestamp": timestamp, "frame": jpeg}, namespace="/data")
        assert self.results.get(timeout=10)["timestamp"] == timestamp
        return (time.perf_counter() - start) * 1000

    def close(self) -> None:
        self.sio.disconnect()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--per-round", type=int, default=40, help="requests per path and round")
    parser.add_argument("--model", type=Path, help="ONNX model (default: a tiny one made here)")
    parser.add_argument("--tls", action="store_true", help="replicas serve HTTPS and forward to each other over TLS")
    args = parser.parse_args()
    workdir = Path(tempfile.mkdtemp(prefix="netapp-forwarding-"))
    tls_args: tuple[str, ...] = ()
    if args.tls:
        ca = certificate_authority(workdir / "ca")
        cert, key = ca.issue(workdir / "replica")
        tls_args = ("--tls-cert", str(cert), "--tls-key", str(key), "--peer-ca", str(ca.cert))
        os.environ["REQUESTS_CA_BUNDLE"] = str(ca.cert)  # this benchmark's requests trust the replicas' CA
    model = args.model or yolox_model(workdir / "tiny.onnx", TINY_BOX, class_id=2)
    jpeg = frame_jpeg()
    samples: dict[str, list[float]] = {}

    def timed(name: str, call) -> None:
        for _ in range(args.per_round):
            start = time.perf_counter()
            call()
            samples.setdefault(name, []).append((time.perf_counter() - start) * 1000)

    scheme = "https" if args.tls else "http"
    with Replicas(model, count=2, scheme=scheme, extra_args=tls_args, balanced=False) as replicas:
        owner, other = replicas.urls
        register = requests.post(f"{owner}/register", json={}, timeout=5).json()["session_id"]
        waiter = requests.post(f"{owner}/register", json={}, timeout=5).json()["session_id"]
        poll = {"X-Session-Id": register}
        frame = {"X-Session-Id": register, "Content-Type": "image/jpeg"}
        wait = {"X-Session-Id": waiter, "Content-Type": "image/jpeg"}
        to_owner, to_other = requests.Session(), requests.Session()  # keep-alive, as a robot's pool
        balancers = [] if args.tls else [HAProxy([], config=routing_config(owner, u)).start() for u in (owner, other)]
        robots = {
            via: SocketIORobot(b.url) for via, b in zip(("direct", "relayed"), balancers, strict=False)
        }  # none with --tls
        try:
            for n in range(args.rounds + 1):  # round 0 warms every path up and is not counted
                if n == 1:
                    samples.clear()
                for via, session, url in (("direct", to_owner, owner), ("forwarded", to_other, other)):
                    timed(f"GET /results|{via}", lambda s=session, u=url: s.get(f"{u}/results", headers=poll))
                    timed(
                        f"POST /send_image (polled)|{via}",
                        lambda s=session, u=url: s.post(f"{u}/send_image", data=jpeg, headers=frame),
                    )
                for via, session, url in (("direct", to_owner, owner), ("other replica", to_other, other)):
                    timed(
                        f"POST /send_image?wait=true|{via}",
                        lambda s=session, u=url: s.post(f"{u}/send_image?wait=true", data=jpeg, headers=wait),
                    )
                for via, robot in robots.items():
                    for i in range(args.per_round):
                        samples.setdefault(f"Socket.IO frame -> result|{via}", []).append(
                            robot.round_trip_ms(jpeg, n * 10_000 + i)
                        )
        finally:
            for robot in robots.values():
                robot.close()
            for balancer in balancers:
                balancer.stop()
    table = render(samples, len(jpeg), "HTTPS between replicas (TLS)" if args.tls else "plain HTTP")
    print(table)
    out = ROOT / "results" / f"forwarding-{time.strftime('%Y%m%d-%H%M%S')}.md"
    out.parent.mkdir(exist_ok=True)
    out.write_text(table + "\n")
    print(f"written to {out}")
    return 0


def render(samples: dict[str, list[float]], jpeg_bytes: int, scheme: str) -> str:
    count = len(next(iter(samples.values())))
    lines = [
        f"{scheme}; JPEG frame: 640x480, {jpeg_bytes / 1024:.0f} KiB; {count} samples a row",
        "",
        "| request | path | p50 ms | p95 ms | extra p50 ms |",
        "|---|---|---:|---:|---:|",
    ]
    requests_seen = list(dict.fromkeys(key.split("|")[0] for key in samples))
    for request in requests_seen:
        rows = {key.split("|")[1]: values for key, values in samples.items() if key.startswith(request + "|")}
        direct = statistics.median(rows["direct"])
        for via, values in rows.items():
            p50 = statistics.median(values)
            extra = "" if via == "direct" else f"{p50 - direct:+.2f}"
            lines.append(f"| {request} | {via} | {p50:.2f} | {percentile(values, 95):.2f} | {extra} |")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
