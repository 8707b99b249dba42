"""`netapp demo`: start a local netapp, stream a sample through the robot client, print a summary, stop cleanly."""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import requests

SAMPLE_IMAGE_URL = "https://raw.githubusercontent.com/Megvii-BaseDetection/YOLOX/main/assets/dog.jpg"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--model", required=True, help="ONNX model path or URL (downloaded once into a cache)")
    parser.add_argument("--source", help="video, image or camera index (default: a sample image, downloaded)")
    parser.add_argument("--transport", choices=("http", "ws", "h264"), default="ws")
    parser.add_argument("--fps", type=float, default=10.0)
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--size", default="640x480", help="resize frames to WIDTHxHEIGHT (default 640x480)")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_ready(url: str, process: subprocess.Popen, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"the netapp exited with code {process.returncode} before it was ready (see above)")
        try:
            if requests.get(f"{url}/readyz", timeout=1).status_code == 200:
                return
        except requests.RequestException:
            pass
        time.sleep(0.1)  # polling with a deadline
    raise RuntimeError(f"the netapp was not ready within {timeout_s} s")


def run(args: argparse.Namespace) -> int:
    from netapp.client import NetAppClient
    from netapp.client.cli import parse_size
    from netapp.client.sources import SourceError, open_source
    from netapp.client.stats import format_summary
    from netapp.client.streaming import stream
    from netapp.server.model_source import DEFAULT_CACHE, ModelUnavailable, resolve_model

    try:
        model = resolve_model(args.model)
        source = args.source or str(resolve_model(SAMPLE_IMAGE_URL, cache_dir=DEFAULT_CACHE.parent / "media", option="--source"))
    except ModelUnavailable as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    print(f"starting a netapp with {model} on {url}", file=sys.stderr)
    server = subprocess.Popen(
        [sys.executable, "-m", "netapp", "--log-level", "WARNING", "serve", "--model", str(model), "--port", str(port)],
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        wait_ready(url, server, timeout_s=120)
        print(f"streaming {Path(source).name} at {args.fps:g} fps for {args.duration:g} s over {args.transport}",
              file=sys.stderr)  # fmt: skip
        frames = open_source(source, args.fps, parse_size(args.size))
        with NetAppClient(url, transport=args.transport, robot_id="demo-robot") as client:
            summary = stream(client, frames, args.fps, args.duration, None if args.json else sys.stderr)
    except (RuntimeError, SourceError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    finally:
        server.send_signal(signal.SIGINT)
        try:
            server.wait(timeout=15)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()
    print(json.dumps(summary) if args.json else format_summary(summary))
    print(f"netapp stopped (exit code {server.returncode})", file=sys.stderr)
    return 0 if summary["results"] > 0 else 1
