"""What frame tracing costs (docs/tracing.md): off, at 1 % sampling and at 100 %, in one run, one table.

    python -m bench.tracing                      # the tiny model (the data path's cost, not the model's)
    python -m bench.tracing --model ../shared/models/yolox_nano.onnx --frames 400
    python -m bench.tracing --quick              # a few frames: that it runs

Two measurements per mode, interleaved over `--repeat` rounds:

- `code`: the tracing code a frame runs, robot and netapp side together, in a tight loop with the real objects
  (`FrameTraces`: begin, on the wire, received; `FrameTracing`: begin, finish) exporting to a real OTLP receiver:
  the data path thread's CPU per frame, and the whole process' (the SDK's export thread included).
- `e2e`: a real `netapp serve` (tracing configured by the OTEL_* variables, as in a pod) and a real NetAppClient over
  `frames`, one frame in flight, `--frames` frames: latency p50/p95 and each side's CPU per frame.

The OTLP receiver (tests/support/otlp.py) runs as a process of its own, so decoding the spans costs neither side.
Off means no endpoint: no SDK is even imported (the `None` checks are all that runs). Quote `uptime` with any figure.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np
import psutil
import requests

from bench.netapps import netapp_process
from netapp.client import NetAppClient
from netapp.client.tracing import FrameTraces
from netapp.protocol import TRACE_CLOCK_FIELD
from netapp.server.pipeline.frame import Frame
from netapp.server.pipeline.tracing import FrameTracing
from netapp.tracing import TraceConfig, Tracer, wall_minus_monotonic_ns
from tests.support.images import make_jpeg
from tests.support.onnx_models import TINY_BOX, yolox_model

ROOT = Path(__file__).resolve().parent.parent
MODES = {"off": None, "1%": 0.01, "100%": 1.0}  # the sampling ratio (None: tracing not configured)
WARM_UP = 20  # frames before the timed ones of an end-to-end run
FLUSH_EVERY = 200  # sampled code-cost frames between exports (8 spans each stay within the SDK's queue of 2048)


@contextlib.contextmanager
def receiver() -> Iterator[str]:
    """An OTLP/HTTP receiver in its own process; its base URL."""
    with tempfile.TemporaryDirectory() as tmp:
        port_file = Path(tmp) / "port"
        process = subprocess.Popen([sys.executable, "-m", "tests.support.otlp", str(port_file)], cwd=ROOT)
        try:
            deadline = time.monotonic() + 30
            while not port_file.is_file() or not port_file.read_text():
                if process.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError("the OTLP receiver did not start")
                time.sleep(0.05)  # polling for the port file, with a deadline
            yield f"http://127.0.0.1:{port_file.read_text()}"
        finally:
            process.terminate()
            process.wait(10)


def spans_received(endpoint: str) -> int:
    return requests.get(f"{endpoint}/stats", timeout=5).json()["spans"]


def tracers(endpoint: str, ratio: float | None) -> tuple[Tracer | None, Tracer | None]:
    """(the robot's, the netapp's) for a mode: the robot decides by the ratio, the netapp follows it."""
    if ratio is None:
        return None, None
    url = f"{endpoint}/v1/traces"
    robot = Tracer(TraceConfig(url, "bench-robot", "always_on" if ratio >= 1 else "traceidratio", ratio))
    netapp = Tracer(TraceConfig(url, "bench-netapp", "parentbased_always_on"))
    return robot, netapp


def code_cost(endpoint: str, ratio: float | None, frames: int) -> dict[str, float]:
    """The per-frame tracing code, both sides, as the data path runs it: µs of this thread's CPU and of the
    process's (export thread included), per frame."""
    robot_tracer, netapp_tracer = tracers(endpoint, ratio)
    traces = FrameTraces(robot_tracer, "frames") if robot_tracer is not None else None
    tracing = FrameTracing(netapp_tracer) if netapp_tracer is not None else None
    session = SimpleNamespace(id="bench-session", robot_id="bench-robot")
    clock = wall_minus_monotonic_ns()
    sampled = 0
    thread0, process0 = time.thread_time_ns(), time.process_time_ns()
    for ts in range(frames):
        t1 = time.monotonic_ns()
        fields = traces.begin(ts, t1) if traces is not None else None  # the sender
        if traces is not None:
            traces.on_wire(ts, t1 + 1000)
        trace = tracing.begin(fields.get("traceparent"), None) if tracing is not None and fields else None  # submit
        recv = t1 + 2000
        message = {
            "timestamp": ts,
            "recv_timestamp": recv,
            "timestamp_before_process": recv + 1000,
            "timestamp_after_process": recv + 2000,
            "send_timestamp": recv + 3000,
        }
        if trace is not None:  # delivery
            message[TRACE_CLOCK_FIELD] = clock
            frame = Frame(ts, recv, ts, "frames", trace=trace, decoded_ns=(recv + 500, recv + 900), turn_ns=recv + 400)
            tracing.finish(session, frame, message, recv + 3000, clock)  # type: ignore[arg-type]
        if traces is not None:  # the receiver
            traces.received(ts, recv + 4000, message, 0, "http://bench")
        sampled += trace is not None
        if trace is not None and sampled % FLUSH_EVERY == 0:  # far faster than a camera: within the SDK's queue
            for tracer in (robot_tracer, netapp_tracer):
                if tracer is not None:
                    thread_paused = time.thread_time_ns()
                    tracer.flush(30)
                    thread0 += time.thread_time_ns() - thread_paused  # the export is not the data path's
    thread = time.thread_time_ns() - thread0
    for tracer in (robot_tracer, netapp_tracer):
        if tracer is not None:
            tracer.flush(30)
    process = time.process_time_ns() - process0
    for tracer in (robot_tracer, netapp_tracer):
        if tracer is not None:
            tracer.shutdown()
    return {"thread_us": thread / frames / 1e3, "process_us": process / frames / 1e3}


def end_to_end(model: str, endpoint: str, ratio: float | None, frames: int) -> dict[str, float]:
    """A real netapp process and a real robot, lockstep: latency and each side's CPU per frame, and the spans."""
    robot_tracer, _ = tracers(endpoint, ratio)
    env = {k: v for k, v in os.environ.items() if not k.startswith("OTEL_")}
    if ratio is not None:  # the netapp configured as a pod would be: by the OTel variables
        env.update(
            OTEL_EXPORTER_OTLP_ENDPOINT=endpoint,
            OTEL_TRACES_SAMPLER="parentbased_always_on",
            OTEL_SERVICE_NAME="bench-netapp",
        )
    before = spans_received(endpoint)
    image = cv2.imdecode(np.frombuffer(make_jpeg(640, 480), np.uint8), cv2.IMREAD_COLOR)
    latencies: list[float] = []
    with patched_environ(env), netapp_process(model, ("--lanes", "1")) as (server, port):
        netapp = psutil.Process(server.pid)
        with NetAppClient(f"http://127.0.0.1:{port}", transport="frames", max_in_flight=1, tracer=robot_tracer) as c:
            for _ in range(WARM_UP):  # warm up: sessions, the model's first runs
                c.send(image)
                next(c.results(timeout=10))
            robot0, netapp0 = time.process_time_ns(), sum(netapp.cpu_times()[:2])
            for _ in range(frames):
                c.send(image)
                latencies.append(next(c.results(timeout=10)).latency_ms)
            robot_cpu, netapp_cpu = time.process_time_ns() - robot0, sum(netapp.cpu_times()[:2]) - netapp0
        server.terminate()  # flushes its spans at exit
        server.wait(20)
    if robot_tracer is not None:
        robot_tracer.shutdown()
    latencies.sort()
    return {
        "p50_ms": statistics.median(latencies),
        "p95_ms": latencies[int(0.95 * (len(latencies) - 1))],
        "robot_cpu_ms": robot_cpu / frames / 1e6,
        "netapp_cpu_ms": netapp_cpu / frames * 1e3,
        "spans_per_frame": (spans_received(endpoint) - before) / (frames + WARM_UP),
    }


@contextlib.contextmanager
def patched_environ(env: dict[str, str]) -> Iterator[None]:
    """os.environ as `env` while the netapp process starts (it inherits it)."""
    saved = dict(os.environ)
    os.environ.clear()
    os.environ.update(env)
    try:
        yield
    finally:
        os.environ.clear()
        os.environ.update(saved)


def table(rows: dict[str, list[dict[str, Any]]], frames: int, code_frames: int) -> str:
    def med(mode: str, key: str) -> float:
        return statistics.median(r[key] for r in rows[mode])

    lines = [
        "| mode | code: data-path thread µs/frame | code: process µs/frame | e2e p50 ms | e2e p95 ms "
        "| robot CPU ms/frame | netapp CPU ms/frame | spans per frame |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for mode in rows:
        lines.append(
            f"| {mode} | {med(mode, 'thread_us'):.2f} | {med(mode, 'process_us'):.2f} | {med(mode, 'p50_ms'):.2f} "
            f"| {med(mode, 'p95_ms'):.2f} | {med(mode, 'robot_cpu_ms'):.3f} | {med(mode, 'netapp_cpu_ms'):.3f} "
            f"| {statistics.mean(r['spans_per_frame'] for r in rows[mode]):.3f} |"
        )
    note = f"(code: {code_frames} frames a round; e2e: {frames} frames a round; medians, spans: the mean)"
    return "\n".join(lines) + "\n\n" + note


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", help="an ONNX detector (default: a tiny YOLOX-layout model made here)")
    parser.add_argument("--frames", type=int, default=1000, help="frames per end-to-end run")
    parser.add_argument("--code-frames", type=int, default=20000, help="frames per code-cost run")
    parser.add_argument("--repeat", type=int, default=3, help="interleaved rounds")
    parser.add_argument("--quick", action="store_true", help="a few frames, one round: that it runs, not figures")
    args = parser.parse_args()
    if args.quick:
        args.frames, args.code_frames, args.repeat = 30, 500, 1
    with tempfile.TemporaryDirectory() as tmp, receiver() as endpoint:
        model = args.model or str(yolox_model(Path(tmp) / "tiny.onnx", TINY_BOX, class_id=2))
        rows: dict[str, list[dict[str, Any]]] = {mode: [] for mode in MODES}
        for _ in range(args.repeat):
            for mode, ratio in MODES.items():
                row = code_cost(endpoint, ratio, args.code_frames)
                row.update(end_to_end(model, endpoint, ratio, args.frames))
                rows[mode].append(row)
                print(mode, {k: round(v, 3) for k, v in row.items()}, flush=True)
    print()
    print(table(rows, args.frames, args.code_frames))
    print()
    print("load:", os.getloadavg(), subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    return 0


if __name__ == "__main__":
    sys.exit(main())
