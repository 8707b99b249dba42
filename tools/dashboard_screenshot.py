#!/usr/bin/env python3
"""A picture of one of the chart's Grafana dashboards drawn from a real Prometheus's data, for docs/operating.md
(Grafana itself is in no registry reachable here):

    python -m tools.dashboard_screenshot [--model ../shared/models/yolox_nano.onnx] [--out docs/monitoring-netapp.png]

starts `netapp serve` (one inference at a time on one thread) and Debian's Prometheus scraping it every second with
the chart's recording rules (files/rules.yaml, 15 s windows); robots stream to it in three phases: 2 robots at 10
FPS, 8 at 30 FPS (more than it serves), 2 again; then it runs every query of the dashboard over that time
(query_range, 1 s steps) and draws each panel as Grafana lays it out, with matplotlib.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
import tempfile
import threading
import time
from pathlib import Path

from netapp.serve_process import free_port

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared"
DASHBOARDS = ROOT / "charts" / "netapp-toolkit" / "files" / "dashboards"
PHASES = ((2, 10.0, 20.0), (8, 30.0, 25.0), (2, 10.0, 20.0))  # (robots, FPS each, seconds)
VARIABLES = {"$__rate_interval": "15s", "$namespace": ".+", "$netapp": ".+", "$robot": ".+"}
UNITS = {"s": ("ms", 1000.0), "percentunit": ("%", 100.0), "reqps": ("/s", 1.0), "short": ("", 1.0)}


def _legend(template: str, labels: dict[str, str]) -> str:
    for key, value in labels.items():
        template = template.replace("{{" + key + "}}", value)
    return template


def draw(board: dict, series: list[list[tuple[str, list[float], list[float]]]], t0: float, out: Path) -> None:
    """Each panel of `board` with its series [(legend, times, values)], Grafana's dark theme, two panels a row."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = board["panels"]
    rows = math.ceil(len(panels) / 2)
    plt.style.use("dark_background")
    fig, axes = plt.subplots(rows, 2, figsize=(16, 3.2 * rows + 0.8), squeeze=False)
    fig.patch.set_facecolor("#111217")
    fig.suptitle(f"{board['title']}  (Prometheus data, drawn by tools/dashboard_screenshot.py)", color="#ccccdc")
    for ax, panel, lines in zip(axes.flat, panels, series, strict=False):
        unit, scale = UNITS.get(panel["fieldConfig"]["defaults"].get("unit", "short"), ("", 1.0))
        ax.set_facecolor("#181b1f")
        ax.set_title(panel["title"], loc="left", fontsize=10, color="#ccccdc")
        for legend, times, values in lines:
            ax.plot([t - t0 for t in times], [v * scale for v in values], linewidth=1.4, label=legend)
        ax.grid(color="#2c3235", linewidth=0.6)
        ax.tick_params(colors="#9fa7b3", labelsize=8)
        ax.set_ylabel(unit, color="#9fa7b3", fontsize=8)
        ax.set_xlabel("seconds", color="#9fa7b3", fontsize=8)
        if lines:
            ax.legend(fontsize=7, loc="upper left", frameon=False, ncol=2)
        else:
            ax.text(0.5, 0.5, "No data", transform=ax.transAxes, ha="center", color="#9fa7b3")
    for ax in list(axes.flat)[len(panels) :]:
        ax.set_visible(False)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    fig.savefig(out, dpi=80, facecolor=fig.get_facecolor())


def main(argv: list[str] | None = None) -> int:
    from netapp.client.netapp_client import NetAppClient
    from netapp.serve_process import wait_http_ok
    from tests.monitoring.monitoring_helpers import render_rules
    from tests.monitoring.prometheus_stack import prometheus
    from tests.support.images import make_jpeg
    from tools.fetch_tools import ensure

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=str(SHARED / "models" / "yolox_nano.onnx"))
    parser.add_argument("--dashboard", default="netapp-netapp", help="a file of charts/netapp-toolkit/files/dashboards")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "monitoring-netapp.png")
    args = parser.parse_args(argv)
    import subprocess

    board = json.loads((DASHBOARDS / f"{args.dashboard}.json").read_text())
    port = free_port()
    netapp = [sys.executable, "-m", "netapp", "--log-level", "WARNING", "serve", "--model", args.model]
    netapp += ["--port", str(port), "--max-batch", "1", "--lanes", "1", "--threads", "1"]
    jpeg = make_jpeg()
    with tempfile.TemporaryDirectory() as tmp, contextlib.ExitStack() as stack:
        directory = Path(tmp)
        proc = subprocess.Popen(netapp, stdin=subprocess.DEVNULL)
        stack.callback(proc.wait, 20)
        stack.callback(proc.terminate)
        wait_http_ok(f"http://127.0.0.1:{port}/readyz", proc, timeout_s=120)
        # The chart's rules, rendered by helm as the tests do, with 15 s windows (the alerts have no Alertmanager).
        rules = render_rules(ensure("helm"), directory, {"window": "15s"})
        labels = {"namespace": "robots", "netapp": "object-detection", "pool": "edge", "pod": "object-detection-0"}
        jobs = {"netapps": [(f"127.0.0.1:{port}", labels)]}
        prom = stack.enter_context(prometheus(directory, jobs, rules, scrape="1s"))
        t0 = time.time()
        for robots, fps, seconds in PHASES:
            stop = threading.Event()
            clients = [NetAppClient(f"http://127.0.0.1:{port}", transport="ws").__enter__() for _ in range(robots)]

            def stream(client: NetAppClient, fps: float = fps, stop: threading.Event = stop) -> None:
                while not stop.is_set():
                    client.send(jpeg)
                    stop.wait(1 / fps)

            threads = [threading.Thread(target=stream, args=(c,), daemon=True) for c in clients]
            for t in threads:
                t.start()
            time.sleep(seconds)  # the phase's length
            stop.set()
            for t in threads:
                t.join(10)
            for c in clients:
                c.close()
            print(f"{robots} robots at {fps:g} FPS for {seconds:g} s", flush=True)
        time.sleep(5)  # the last scrapes and rule evaluations
        t1 = time.time()
        series = []
        for panel in board["panels"]:
            lines = []
            for target in panel["targets"]:
                expr = target["expr"]
                for name, value in VARIABLES.items():
                    expr = expr.replace(name, value)
                for result in prom.query_range(expr, t0, t1, 1.0):
                    points = [(float(t), float(v)) for t, v in result["values"] if v not in ("NaN", "+Inf", "-Inf")]
                    if points:
                        times, values = zip(*points, strict=True)
                        lines.append((_legend(target["legendFormat"], result["metric"]), list(times), list(values)))
            series.append(lines)
    draw(board, series, t0, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
