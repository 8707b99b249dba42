"""Where the netapp's per-frame time goes: py-spy samples the netapp and the robot while one transport streams, and
the samples are sorted into the stages of the data path, in CPU microseconds per frame.

    python -m bench.overhead_profile --transports http,ws,h264,frames,frames-h264 --fps 25 --duration 15

Each robot (bench/robot.py, pre-encoded JPEG; H.264 encodes live) streams to a warmed-up netapp while `py-spy
record` samples both processes (every thread, not pausing them: pausing doubles the latencies). A sample is given
to the first stage in STAGES whose pattern appears anywhere in its stack (so a json.dumps called by socket.io's
packet encoder is serialisation, not socket.io); one whose innermost frame is a wait (IDLE) is left out.
Writes profile.md and the raw stacks under results/overhead-profile-<time>/.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import re
import shutil
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

from bench.netapps import netapp_process, start_run
from bench.transports import run_robot

ROOT = Path(__file__).resolve().parent.parent

# (stage, pattern in a stack), first match wins: the order puts the specific before the general.
STAGES = [
    ("model (onnxruntime + output decoding)", r"process \(netapp/models/detector\.py"),
    # H.264 is decoded inside the pipeline's `_prepare`, on the lane: before the JPEG stage, which that names.
    ("H.264 bitstream checks", r"h264_bitstream\.py"),
    ("H.264 decode (PyAV)", r"netapp/server/decoding/h264\.py"),
    ("JPEG decode + letterbox", r"_prepare \(netapp/server/pipeline/pipeline\.py|decode_jpeg|letterbox"),
    ("H.264 encode (robot)", r"netapp/client/h264\.py|netapp/client/encoders\.py"),
    ("frame resize to the netapp's input size (robot)", r"_resized \(netapp/client/sender\.py"),
    ("JPEG header checks", r"image_limits\.py|jpeg_frame"),
    ("frames wire format (pack, parse)", r"netapp/framing\.py"),
    ("JSON (results, bodies)", r"\bjson/|orjson|ujson|render \(starlette|\.json \(requests"),
    ("socket.io packets", r"socketio/(async_)?packet\.py|socketio/packet\.py"),
    ("engine.io packets", r"engineio/(async_)?packet\.py|engineio/packet\.py|engineio/payload\.py"),
    ("WebSocket frames (websockets / websocket-client / simple-websocket)", r"websockets/|websocket/|simple_websocket"),
    ("socket.io dispatch", r"socketio/"),
    ("engine.io dispatch", r"engineio/"),
    ("HTTP client (requests, urllib3, http.client)", r"requests/|urllib3/|http/client\.py"),
    ("HTTP server (h11, uvicorn)", r"h11/|uvicorn/protocols/http"),
    ("FastAPI / Starlette route", r"fastapi/|starlette/"),
    ("netapp pipeline (hand-offs, counting)", r"netapp/server/pipeline/|netapp/server/dataplane\.py|prometheus_client"),
    ("netapp transports (server)", r"netapp/server/"),
    ("netapp client", r"netapp/(client|apps)/"),
    ("thread pools, futures", r"concurrent/futures|threading\.py"),
    ("asyncio loop", r"asyncio/|uvloop"),
]


# py-spy's own idle detection needs to pause the process; without it, a sample whose innermost frame is one of these
# waits is a thread waiting (a pool for work, a reader for the socket, the event loop in epoll), not working.
IDLE = re.compile(
    # websockets' sync client: its reader waits in its selector, `recv()` in its assembler's queue
    # the robot's pacing: `time.sleep` is C, so the innermost Python frame is the one that calls it
    r"^(Condition\.wait|Event\.wait|Queue\.get|SimpleQueue\.get|_worker|Runner\.run|select|poll|do_poll|sleep|_sleep_until|"
    r"\w*Selector\.select|Assembler\.get_next_frame|"
    r"recv|_recv|recv_into|readinto|SocketIO\.readinto|Thread\.join|_wait_for_tstate_lock|wait) "
)


def classify(stack: str) -> str:
    leaf = stack.rsplit(";", 1)[-1]
    if IDLE.match(leaf):
        return "idle"
    for name, pattern in STAGES:
        if re.search(pattern, stack):
            return name
    return "other"


def read_raw(path: Path) -> Counter:
    """py-spy's raw format (one `frames... count` a line) -> samples per stage."""
    counts: Counter = Counter()
    if not path.is_file():
        return counts
    for line in path.read_text().splitlines():
        stack, _, n = line.rpartition(" ")
        if n.isdigit():
            counts[classify(stack)] += int(n)
    return counts


@contextlib.contextmanager
def sampled(pid: int, out: Path, rate: int, duration: float):
    spy = shutil.which("py-spy", path=str(Path(sys.executable).parent)) or "py-spy"
    cmd = [spy, "record", "--pid", str(pid), "--rate", str(rate), "--format", "raw", "--threads", "--nonblocking"]
    proc = subprocess.Popen(
        [*cmd, "--duration", str(int(duration)), "-o", str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        yield
    finally:
        proc.wait(timeout=duration + 60)


def main() -> int:
    shared = ROOT.parent / "shared"
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", default=str(shared / "models" / "yolox_nano.onnx"))
    p.add_argument("--video", default=str(shared / "media" / "pedestrians.avi"))
    p.add_argument("--transports", default="http,ws,h264,frames,frames-h264")
    p.add_argument("--fps", type=float, default=25.0)
    p.add_argument("--duration", type=float, default=15.0, help="seconds each transport streams")
    p.add_argument("--rate", type=int, default=500, help="py-spy samples per second")
    p.add_argument("--size", default="640x480")
    p.add_argument("--serve-args", default="")
    p.add_argument("--out", default=str(ROOT / "results"))
    args = p.parse_args()
    args.pre_encode = True
    out_dir = start_run("overhead-profile", args.out, (args.model, args.video))
    if out_dir is None:
        return 2
    report = []
    with netapp_process(args.model, args.serve_args.split()) as (server, port):
        url = f"http://127.0.0.1:{port}"
        run_robot(args, "ws", 25, url, server.pid, duration=8)  # warm-up
        for transport in args.transports.split(","):
            server_raw, robot_raw = out_dir / f"{transport}-netapp.txt", out_dir / f"{transport}-robot.txt"
            robot = robot_profiled(args, transport, url, server.pid, server_raw, robot_raw)
            frames = max(1.0, robot["results_per_s"] * sampled_s(args))
            parts = robot.get("latency_breakdown_ms") or {}
            report.append(
                f"\n### {transport} @ {args.fps:g} FPS: {frames} results, breakdown (wall, p50 ms): {parts}\n"
            )
            report.append("| process | stage | CPU µs/frame | share |")
            report.append("|---|---|---|---|")
            for name, raw in (("netapp", server_raw), ("robot", robot_raw)):
                counts = read_raw(raw)
                counts.pop("idle", None)
                total = sum(counts.values()) or 1
                for stage, n in counts.most_common():
                    us = n / args.rate / frames * 1e6
                    report.append(f"| {name} | {stage} | {us:.0f} | {100 * n / total:.0f}% |")
            print(report[-1], file=sys.stderr)
    text = "\n".join(report) + "\n"
    (out_dir / "profile.md").write_text(text)
    print(text)
    print(f"written: {out_dir}/profile.md and the raw stacks (*-netapp.txt, *-robot.txt)")
    return 0


def sampled_s(args) -> float:
    return int(args.duration - 1)


def robot_profiled(args, transport: str, url: str, server_pid: int, server_raw: Path, robot_raw: Path) -> dict:
    """bench/robot.py for `args.duration` s; py-spy samples it and the netapp while it streams (after its start-up),
    for `sampled_s` seconds."""
    cmd = [sys.executable, "-m", "bench.robot", "--transport", transport, "--url", url]
    cmd += ["--video", args.video, "--fps", str(args.fps), "--duration", str(args.duration), "--size", args.size]
    cmd += ["--pre-encode"]
    robot = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    assert robot.stdout is not None
    first = robot.stdout.readline()  # {"streaming_at": ...}: the robot streams from here
    if not first.startswith("{"):
        raise RuntimeError(f"robot {transport} did not start: {first!r}")
    with (
        sampled(robot.pid, robot_raw, args.rate, sampled_s(args)),
        sampled(server_pid, server_raw, args.rate, sampled_s(args)),
    ):
        out = robot.stdout.read()
    robot.wait()
    time.sleep(0.5)
    return json.loads(out.strip().splitlines()[-1])


if __name__ == "__main__":
    raise SystemExit(main())
