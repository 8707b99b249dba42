"""Wake benchmark: a robot's first request for an app asleep at zero -> its first result (local backend).

    flock /tmp/heavy.lock python -m bench.wake --model ../shared/models/yolox_nano.onnx --runs 5

The middleware (local backend) runs in this process with the catalogue's object-detection app saying
`scaling.idleToZero: 1s`. A first robot deploys it and leaves its netapp (keeping its deployment), so the netapp
process is stopped (phase Idle). Then, per run, two ways to wake it, each timed from the robot's first request to
its first result, with every error on the way counted:

- `ask`: another robot asks the middleware for the app (`POST /deployments` with `wait`: one request held until the
  netapp is Ready), connects to the URL it is given and sends a frame every 50 ms until a result comes back;
- `holder`: the first robot connects again to the URL it still holds: the sleeping port answers 503 `waking`, the
  client tries again on its short schedule (netapp.client.link.WAKE_RETRY_S) and sends as above.

The netapp is put back to sleep between runs. The load average is printed beside the figures (2 shared cores).
"""

from __future__ import annotations

import argparse
import copy
import os
import queue
import statistics
import subprocess
import sys
import time
from typing import Any

import cv2

from bench.robot import robot_jpeg
from bench.switchover import ROBOT, SECRET, Middleware
from netapp.client.errors import NetAppError
from netapp.client.middleware import MiddlewareClient
from netapp.client.netapp_client import NetAppClient
from netapp.serve_process import free_port, wait_http_ok

IDLE_TO_ZERO = "1s"
SEND_EVERY_S = 0.05


def first_result(url: str, frame: bytes, timeout_s: float) -> tuple[float, int]:
    """Connect to `url` and send `frame` until a result comes back: (seconds, error events on the way)."""
    results: queue.Queue[Any] = queue.Queue()
    errors: list[Any] = []
    started = time.monotonic()
    with NetAppClient(url, on_result=results.put, on_error=errors.append) as client:
        deadline = started + timeout_s
        while time.monotonic() < deadline:
            client.send(frame)
            try:
                results.get(timeout=SEND_EVERY_S)
                return time.monotonic() - started, len(errors)
            except queue.Empty:
                continue
    raise TimeoutError(f"no result from {url} within {timeout_s:.0f} s")


def serve_start_s(model: str) -> float:
    """`netapp serve` exec -> /readyz, alone (the part of a wake that is the netapp's own start)."""
    port = free_port()
    started = time.monotonic()
    argv = [sys.executable, "-m", "netapp", "serve", "--model", model, "--port", str(port)]
    with subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) as proc:
        try:
            wait_http_ok(f"http://127.0.0.1:{port}/readyz", proc, 60.0, interval_s=0.025)
            return time.monotonic() - started
        finally:
            proc.terminate()
            proc.wait(10)


def asleep(mw: MiddlewareClient, deployment: str, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while mw.status(deployment)["status"] != "Idle":
        if time.monotonic() > deadline:
            raise RuntimeError("the netapp did not go to sleep")
        time.sleep(0.05)


def one_run(middleware: Middleware, holder: MiddlewareClient, endpoint: Any, frame: bytes, mode: str) -> dict:
    asleep(holder, endpoint.deployment_id)
    time.sleep(0.2)  # its wake listener is up
    started = time.monotonic()
    errors = 0
    if mode == "ask":
        with MiddlewareClient(middleware.url, ROBOT, SECRET) as other:
            view = other.create("object-detection", placement="edge", wait=60)
            to_url = time.monotonic() - started
            if view["status"] != "Ready":
                raise RuntimeError(f"not Ready after its wait: {view}")
            to_result, errors = first_result(view["url"], frame, 60)
    else:
        to_url = 0.0
        try:
            to_result, errors = first_result(endpoint.url, frame, 60)
        except NetAppError:
            to_result, errors = float("nan"), 1
    return {"to_url_s": to_url, "to_result_s": time.monotonic() - started, "errors": errors, "client_s": to_result}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", default=os.environ.get("NETAPP_TEST_MODEL"), help="the netapp's ONNX model")
    parser.add_argument("--image", default=os.path.join(os.environ.get("NETAPP_TEST_MEDIA", ""), "dog.jpg"))
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--modes", default="ask,holder")
    args = parser.parse_args()
    if not args.model:
        parser.error("--model is required (or NETAPP_TEST_MODEL)")
    frame = robot_jpeg(cv2.resize(cv2.imread(args.image), (640, 480)))
    catalogue = copy.deepcopy(_catalogue())
    catalogue["object-detection"]["spec"]["scaling"] = {"idleToZero": IDLE_TO_ZERO}
    rows: dict[str, list[dict[str, Any]]] = {}
    with Middleware(args.model, _policy(), catalogue=catalogue, idle_poll_s=0.2) as middleware:
        with MiddlewareClient(middleware.url, ROBOT, SECRET) as holder:
            endpoint = holder.deploy("object-detection", placement="edge", timeout=120)
            for run in range(args.runs):
                for mode in args.modes.split(","):
                    row = one_run(middleware, holder, endpoint, frame, mode)
                    rows.setdefault(mode, []).append(row)
                    print(
                        f"{mode} run {run + 1}: request -> URL {row['to_url_s']:.2f} s, -> first result "
                        f"{row['to_result_s']:.2f} s, errors {row['errors']} (load {os.getloadavg()[0]:.2f})",
                        flush=True,
                    )
    starts = [serve_start_s(args.model) for _ in range(3)]
    load = os.getloadavg()
    print(f"\nidleToZero {IDLE_TO_ZERO}, {args.runs} runs per mode, load average {load[0]:.2f} {load[1]:.2f}")
    print("(median / max)\n")
    print("| from the robot's first request to | " + " | ".join(rows) + " |")
    print("|---|" + "---|" * len(rows))
    for key, label in (("to_url_s", "its URL (ask: the held request)"), ("to_result_s", "its first result")):
        cells = [f"{statistics.median(r[key] for r in v):.2f} / {max(r[key] for r in v):.2f}" for v in rows.values()]
        print(f"| {label} | " + " | ".join(cells) + " |")
    print("| errors on the way | " + " | ".join(str(sum(r["errors"] for r in v)) for v in rows.values()) + " |")
    print(
        f"\nof which the netapp's own start (`netapp serve` exec -> /readyz, alone): median "
        f"{statistics.median(starts):.2f} s, max {max(starts):.2f} s"
    )
    return 0


def _catalogue() -> dict[str, Any]:
    from netapp_middleware.catalogue import DEFAULT_CATALOGUE

    return {"object-detection": DEFAULT_CATALOGUE["object-detection"]}


def _policy() -> Any:
    from netapp_middleware.switchover.decision import SwitchPolicy

    return SwitchPolicy()


if __name__ == "__main__":
    sys.exit(main())
