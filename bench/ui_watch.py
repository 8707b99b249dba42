"""What an open page costs the robots: 4 robots stream to one netapp, with no page open and with one page open on
each robot (its Server-Sent Events read as a browser would), interleaved, from one run.

    python -m bench.ui_watch [--model M] [--video V] [--robots 4] [--fps 5] [--duration 15] [--repeat 2]

Prints a table: per condition, the median over robots and repeats of results/s and latency p50/p95 (each robot's
own summary), the netapp's CPU, and the page events received per second.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

import requests

from bench.transports import ProcessMonitor
from netapp.serve_process import free_port, wait_http_ok

ROOT = Path(__file__).resolve().parent.parent


class Page:
    """One open robot page: reads its event stream in a thread and counts the frames it gets."""

    def __init__(self, url: str) -> None:
        self.events = 0
        self._response = requests.get(url, stream=True, timeout=(5, 60))
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        try:
            for line in self._response.iter_lines():
                if line.startswith(b'data: {"frame"'):
                    self.events += 1
        except requests.RequestException:
            pass

    def close(self) -> None:
        self._response.close()


def run(args, url: str, server_pid: int, pages: bool) -> dict:
    robot = [sys.executable, "-m", "bench.robot", "--transport", "ws", "--url", url]
    robot += ["--video", args.video, "--fps", str(args.fps), "--duration", str(args.duration), "--pre-encode"]
    procs = [subprocess.Popen(robot, stdout=subprocess.PIPE, text=True) for _ in range(args.robots)]
    opened: list[Page] = []
    deadline = time.monotonic() + 300  # robots start slowly on a busy machine
    while len(robots := requests.get(f"{url}/ui/api/robots", timeout=5).json()["robots"]) < args.robots:
        if time.monotonic() > deadline:
            raise RuntimeError("the robots did not connect")
        time.sleep(0.1)  # polling with a deadline
    if pages:
        opened = [Page(f"{url}/ui/api/robots/{r['id']}/events") for r in robots]
    start = time.monotonic()
    with ProcessMonitor(server_pid) as monitor:
        summaries = [json.loads(p.communicate()[0].strip().splitlines()[-1]) for p in procs]
    elapsed = time.monotonic() - start
    for page in opened:
        page.close()
    return {
        "results_per_s": [s["results_per_s"] for s in summaries],
        "p50": [s["latency_ms"]["p50"] for s in summaries],
        "p95": [s["latency_ms"]["p95"] for s in summaries],
        "cpu": monitor.cpu_percent,
        "page_events_per_s": [p.events / elapsed for p in opened],
    }


def main() -> int:
    shared = ROOT.parent / "shared"
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", default=str(shared / "models" / "yolox_nano.onnx"))
    p.add_argument("--video", default=str(shared / "media" / "pedestrians.avi"))
    p.add_argument("--robots", type=int, default=4)
    p.add_argument("--fps", type=float, default=5.0)
    p.add_argument("--duration", type=float, default=15.0)
    p.add_argument("--repeat", type=int, default=2)
    args = p.parse_args()
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    serve = [sys.executable, "-m", "netapp", "--log-level", "WARNING", "serve", "--model", args.model]
    server = subprocess.Popen([*serve, "--port", str(port)])
    rows: dict[str, list[dict]] = {"no page": [], "a page per robot": []}
    try:
        wait_http_ok(f"{url}/readyz", server, 120)
        for _ in range(args.repeat):  # interleaved, so both conditions see the same machine load
            for name in rows:
                rows[name].append(run(args, url, server.pid, pages=name != "no page"))
    finally:
        server.terminate()
        server.wait(timeout=30)

    def med(runs: list[dict], key: str) -> float:
        values = [v for r in runs for v in (r[key] if isinstance(r[key], list) else [r[key]])]
        return statistics.median(values) if values else float("nan")

    print(f"{args.robots} robots, ws, {args.fps:g} fps each, {args.duration:g} s x {args.repeat} interleaved runs")
    print("| pages | results/s per robot | latency p50 ms | latency p95 ms | netapp CPU % | page frames/s |")
    print("|---|---|---|---|---|---|")
    for name, runs in rows.items():
        events = med(runs, "page_events_per_s")
        print(
            f"| {name} | {med(runs, 'results_per_s'):.2f} | {med(runs, 'p50'):.1f} | {med(runs, 'p95'):.1f} "
            f"| {med(runs, 'cpu'):.0f} | {'-' if events != events else f'{events:.1f}'} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
