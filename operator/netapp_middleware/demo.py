"""`netapp middleware demo`: the whole robot flow on this machine, as separate processes.

middleware (local backend) -> `netapp stream --middleware` deploys object-detection, waits until Ready, streams,
prints results, deletes the deployment -> the demo checks that the netapp process is gone -> middleware stops.
"""

from __future__ import annotations

import argparse
import os
import secrets
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

from netapp_operator.constants import DEFAULT_MODEL_URL

from netapp.protocol import TRANSPORTS
from netapp.serve_process import free_port, wait_http_ok

DEMO_ROBOT = "demo-robot"
SAMPLE_IMAGE_URL = "https://raw.githubusercontent.com/Megvii-BaseDetection/YOLOX/main/assets/dog.jpg"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--model",
        default=DEFAULT_MODEL_URL,
        help="ONNX model path or URL for the local netapps (default: YOLOX-Nano, downloaded once)",
    )
    parser.add_argument("--source", help="video, image or camera index (default: a sample image, downloaded)")
    parser.add_argument("--transport", choices=TRANSPORTS, default="ws")
    parser.add_argument("--fps", type=float, default=10.0)
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--placement", default="edge", help="placement to ask for (default edge)")


def _netapp(*argv: str) -> list[str]:
    return [sys.executable, "-m", "netapp", "--log-level", "WARNING", *argv]


def _netapp_pids(middleware_pid: int) -> list[int]:
    import psutil

    try:
        children = psutil.Process(middleware_pid).children(recursive=True)
    except psutil.NoSuchProcess:
        return []
    return [p.pid for p in children if "serve" in p.cmdline() and p.status() != psutil.STATUS_ZOMBIE]


def run(args: argparse.Namespace) -> int:
    from netapp.models.source import DEFAULT_CACHE, ModelUnavailable, resolve_model

    from .auth import hash_secret

    try:  # both up front: offline, the demo says so in one line before starting anything
        model = str(resolve_model(args.model))
        source = args.source or str(
            resolve_model(
                SAMPLE_IMAGE_URL, cache_dir=DEFAULT_CACHE.parent / "media", option="--source", what="the sample image"
            )
        )
    except ModelUnavailable as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    secret = secrets.token_urlsafe(16)
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    with tempfile.TemporaryDirectory(prefix="netapp-demo-") as tmp:
        robots = Path(tmp) / "robots.yaml"
        robots.write_text(f"robots:\n  {DEMO_ROBOT}: '{hash_secret(secret)}'\n")
        print(f"middleware (local backend) on {url}", file=sys.stderr)
        middleware = subprocess.Popen(
            _netapp(
                "middleware",
                "--backend",
                "local",
                "--model",
                model,
                "--robots-file",
                str(robots),
                "--host",
                "127.0.0.1",
                "--port",
                str(port),
            )
        )
        try:
            wait_http_ok(f"{url}/healthz", middleware, 60)
            print(f"robot {DEMO_ROBOT}: netapp stream --middleware {url} --app object-detection", file=sys.stderr)
            code = subprocess.call(
                _netapp(
                    "stream",
                    "--middleware",
                    url,
                    "--app",
                    "object-detection",
                    "--placement",
                    args.placement,
                    "--robot-id",
                    DEMO_ROBOT,
                    "--source",
                    source,
                    "--transport",
                    args.transport,
                    "--fps",
                    str(args.fps),
                    "--duration",
                    str(args.duration),
                ),
                env={**os.environ, "NETAPP_ROBOT_SECRET": secret},
            )
            left = _netapp_pids(middleware.pid)
            print(
                f"deployment deleted: {'no netapp left running' if not left else f'netapps still up: {left}'}",
                file=sys.stderr,
            )
            if left:
                code = code or 1
        except RuntimeError as exc:
            print(f"error: {exc}", file=sys.stderr)
            code = 1
        finally:
            middleware.send_signal(signal.SIGTERM)
            try:
                middleware.wait(timeout=30)
            except subprocess.TimeoutExpired:
                middleware.kill()
                middleware.wait()
        print("middleware stopped", file=sys.stderr)
    return code
