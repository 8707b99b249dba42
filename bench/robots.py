"""Many robots against 1 and 2 replicas behind a real balancer, side by side in one run.

    python -m bench.robots                                   # 1, 4, 8, 16 robots at 25 FPS; 1 and 2 replicas; 15 s
    python -m bench.robots --robots 8 --replicas 1 --duration 10 --variants 'spin=--spin-wait;sleep='
    python -m bench.robots --robots 6,16 --replicas 1 --start storm --transports ws,http,h264,era5g
    python -m bench.robots --model yolo11n-seg.onnx --model-args='--conf 0.0001 --max-detections 20' --robots 8

Each replica is a `netapp serve` process (`--model`, the shared YOLOX-Nano by default, and `--model-args`: any model
the netapp serves, read as it reads it; the hard limit off so every robot is served);
HAProxy (Debian's package: TCP, round robin per connection, like a Service) stands in front of them; robots are
NetAppClients (or, `--transports era5g`, unmodified era-5g-clients), spread evenly over up to 4 robot processes, each
streaming 640x480 frames of ../shared/media/pedestrians.avi at the input rate (pre-encoded JPEG; raw pictures for
robots that encode their own). `--start connected` connects every robot, then all stream from one moment; `--start
storm` starts them all at one moment, each streaming as soon as it is connected. The in-process maximum (decode +
detect, back to back, one process: the same Detector with the same `--model-args`, so a segmentation model's masks
are decoded and encoded there as in the netapp) is measured in the same run, before and after, and the table is
against its median.

Columns: aggregate results/s and its % of the in-process maximum (of the input rate where robots ask for less);
each robot's share of the aggregate (its results/s over the mean: min and max) and fairness (min/max), all counted
in the window where every robot was getting results; latency p50/p95 over every result; frames lost (sent, then
neither a result nor an error came back); replica CPU %; what the replicas' own capacity estimators said at the end
(GET /capacity, summed), beside what they delivered; and how long the slowest robot waited for its first result.
Writes results/robots-<time>/table.md and runs.json (each robot's results/s among them).
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import math
import os
import shlex
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import psutil

from bench.netapps import CLIENT_TRANSPORTS, ENCODES_LIVE, start_run
from bench.robot import jpeg_frames
from netapp.serve_process import free_port, serve_command, wait_http_ok
from netapp.server.access import token_digest

ROOT = Path(__file__).resolve().parent.parent

SOURCE_FPS = 25.0  # the rate the sample video is read at (which of its frames are taken), not the robots' pace
MAX_PROCESSES = 4  # robot processes; robots beyond that share a process, each on its own threads


# -- worker modes (run as subprocesses) -----------------------------------------------------------------------------


def worker_max(args) -> None:
    """The in-process maximum: decode and detect pre-encoded frames back to back for `duration` seconds."""
    from netapp.models import Detector
    from netapp.server.decoding.jpeg import decode_jpeg

    detector = Detector(model_config(args))
    detector.load()
    frames = jpeg_frames(args.video, SOURCE_FPS, args.size, 100)
    start = time.monotonic()
    done = detections = masks = 0
    while time.monotonic() - start < args.duration:
        found = detector.detect(decode_jpeg(frames[done % len(frames)]))
        detections += len(found)
        masks += sum(1 for d in found if d.get("mask"))
        done += 1
    elapsed = time.monotonic() - start
    print(json.dumps({"results_per_s": done / elapsed, "detections": detections / done, "masks": masks / done}))


def model_config(args):
    """The DetectorConfig `netapp serve --model MODEL MODEL_ARGS` makes (its --conf, --iou, --max-detections,
    --mask-format, --task, ...), for the in-process maximum: the same model, read and decoded the same way. Raises
    SystemExit (argparse's message) for flags that are not the netapp's model flags."""
    from netapp.models.options import add_model_arguments, detector_config

    parser = argparse.ArgumentParser(prog="--model-args", add_help=False)
    add_model_arguments(parser)
    parsed = parser.parse_args(shlex.split(args.model_args))
    parsed.threads = 0  # every core: the in-process maximum, as before
    return detector_config(parsed, args.model)


# How the robots' NetAppClients send, compared side by side with --clients.
CLIENTS = {
    "paced": {"pacing": True},  # the default: one frame at a time, held back, while the netapp is the bottleneck
    "unpaced": {"pacing": False},  # every frame due goes as soon as a slot is free (before pacing)
    "one-in-flight": {"pacing": False, "max_in_flight": 1},  # the next frame only once the last result is back
    # Socket.IO's long-polling start, then the upgrade (python-socketio's default, NetAppClient's before): behind
    # two replicas, half the robots' WebSockets are relayed by the replica they land on to their session's owner
    "polling-first": {"websocket_first": False},
}


def client_options(args) -> dict:
    return {"max_in_flight": args.max_in_flight} | CLIENTS[args.client]


# --priorities: the class token the bench's netapps take (`--priority-token high=SHA256`), so a robot may claim high
CLASS_TOKEN = "bench-high-class-token"
NO_PRIORITIES = "none"


def robot_class(assignment: str, i: int) -> str | None:
    """Robot i's class in an assignment such as 'high,low' (robot 0 high, the others low: the last repeats); None
    for 'none' (no robot claims a class: every one is normal, as before priorities)."""
    if assignment == NO_PRIORITIES:
        return None
    classes = assignment.split(",")
    return classes[min(i, len(classes) - 1)]


def raw_frames(video: str, size: tuple[int, int], count: int, fps: float = SOURCE_FPS) -> list:
    """BGR frames, for robots that encode on their own (H.264, the era-5g-client)."""
    from netapp.client.sources import open_source

    return list(itertools.islice(open_source(video, fps, size), count))


# How the robots start (--start): `connected` connects every robot, then all stream from one moment (the bench's
# way before issue 22); `storm` starts them at one moment, each streaming as soon as it is connected (a launch file
# starting a fleet: the connects, the INITs and the first frames all at once).
STARTS = ("connected", "storm")
ENCODING_ROBOTS = (*ENCODES_LIVE, "era5g")
TRANSPORTS = ("ws", "http", "frames", *ENCODING_ROBOTS)  # robots given BGR frames; the others send the pre-encoded JPEG


def unserved(exc: Exception) -> dict:
    """The summary of a robot that got no session: no results (its share 0), the error counted."""
    return {
        "frames_sent": 0,
        "results": 0,
        "results_per_s": 0.0,
        "duration_s": 1.0,
        "lost": 0,
        "errors": 1,
        "within_deadline": 0,
        "within_deadline_per_s": 0.0,
        "latencies_ms": [],
        "failed": repr(exc)[:300],
    }


READY = "ready"  # a robot process's line once its robots can start (with --start connected: once connected)


def worker_robots(args) -> None:
    """`--robots` robots in this process, each a NetAppClient (or an era-5g-client) on its own thread, streaming at
    `--fps` from the moment (wall clock) the orchestrator writes on stdin once every robot process is ready."""
    from bench.era5g_robot import Era5gRobot
    from netapp.apps.streaming import stream
    from netapp.client import NetAppClient

    raw = args.transport in ENCODING_ROBOTS
    frames = raw_frames(args.video, args.size, 50) if raw else jpeg_frames(args.video, SOURCE_FPS, args.size, 100)
    summaries: list[dict] = []
    lock = threading.Lock()
    connected = threading.Barrier(args.robots + 1, timeout=300)  # with --start connected: every robot connected
    go = threading.Event()
    start: dict[str, float] = {}

    def robot(i: int) -> None:
        priority = robot_class(args.priority, args.first + i)
        session = {"args": {"priority": priority}} if priority else {}
        if priority == "high":
            session["token"] = CLASS_TOKEN
        options = client_options(args) | session | {"deadline_ms": args.deadline_ms}
        offset = (i * 7) % len(frames)
        mine = itertools.cycle(frames[offset:] + frames[:offset])
        name = f"robot-{args.first + i}"
        era = args.transport == "era5g"
        arrivals: list[float] = []  # when each result came (wall clock), for the window every robot streamed in
        if era:
            client = Era5gRobot(args.url, name, arrivals)
        else:
            on_result = lambda _: arrivals.append(time.time())  # noqa: E731
            transport, codec = CLIENT_TRANSPORTS[args.transport]
            client = NetAppClient(args.url, transport, codec=codec, robot_id=name, on_result=on_result, **options)
        try:
            if args.start == "connected":
                try:
                    client.connect()
                finally:
                    connected.wait()  # connected or not: the others start all the same
            go.wait()
            time.sleep(max(0.0, start["at"] - time.time()))  # the common start, on the wall clock: pacing
            began = time.time()
            if args.start == "storm":
                client.connect()
            if era:
                summary = client.stream(mine, args.fps, args.duration)
            else:
                summary = stream(client, mine, args.fps, args.duration)
                summary["latencies_ms"] = list(client.stats.latencies_ms)
        except Exception as exc:  # not served (refused, or no session in time): counted as such, not left out
            go.wait()
            summary, began = unserved(exc), time.time()
        finally:
            client.close()
        summary["robot"] = args.first + i
        summary["arrivals"] = arrivals
        summary["started_s"] = began - start["at"]  # when it began to connect (storm) or stream, from the start
        summary["priority"] = priority or "normal"
        with lock:
            summaries.append(summary)

    threads = [threading.Thread(target=robot, args=(i,)) for i in range(args.robots)]
    for t in threads:
        t.start()
    if args.start == "connected":
        connected.wait()
    print(READY, flush=True)
    start["at"] = float(sys.stdin.readline())
    go.set()
    for t in threads:
        t.join()
    print(json.dumps(summaries))


# -- the orchestrator -----------------------------------------------------------------------------------------------


def run_json(cmd: list[str], timeout: float) -> object:
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
    if out.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd[:4])} failed: {out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def base_cmd(args) -> list[str]:
    return [
        sys.executable,
        "-m",
        "bench.robots",
        "--model",
        args.model,
        f"--model-args={args.model_args}",  # with '=': its value starts with a dash
        "--video",
        args.video,
        "--size",
        args.size_text,
    ]


def measure_max(args) -> float:
    found = run_json([*base_cmd(args), "--worker", "max", "--duration", str(args.max_duration)], 300)
    print(
        f"in-process: {found['results_per_s']:.1f} results/s, {found['detections']:.1f} detections and "
        f"{found['masks']:.1f} masks a frame",
        file=sys.stderr,
        flush=True,
    )
    return found["results_per_s"]


@contextlib.contextmanager
def replicas(args, count: int, serve_args: str):
    """`count` netapp processes, each with its share of the cores for onnxruntime, behind HAProxy."""
    from tests.support.haproxy import HAProxy

    threads = max(1, (os.cpu_count() or 1) // count)
    checkout = None
    if serve_args.startswith("@"):  # another checkout's netapp (e.g. main, for a before/after in one run)
        checkout, _, serve_args = serve_args[1:].partition(" ")
    procs, urls = [], []
    try:
        for _ in range(count):
            port = free_port()
            procs.append(
                subprocess.Popen(
                    serve_command(
                        "--model",
                        args.model,
                        *shlex.split(args.model_args),
                        "--port",
                        str(port),
                        *(["--hard-share", "0"] if checkout is None else []),  # serve every robot
                        *(["--priority-token", f"high={token_digest(CLASS_TOKEN)}"] if checkout is None else []),
                        "--threads",
                        str(threads),
                        *serve_args.split(),
                    ),
                    cwd=checkout,
                    # robots share this machine's cores with the replicas; elsewhere they would have their own
                    preexec_fn=(lambda: os.nice(args.netapp_nice)) if args.netapp_nice else None,
                )
            )
            urls.append(f"http://127.0.0.1:{port}")
        for proc, url in zip(procs, urls, strict=True):
            wait_http_ok(url + "/readyz", proc, 120)
        if args.no_balancer:  # one replica, straight to it (a machine without HAProxy: bench/gpu.sh)
            yield urls[0], procs, urls
            return
        with HAProxy(urls) as balancer:
            yield balancer.url, procs, urls
    finally:
        for proc in procs:
            proc.send_signal(signal.SIGINT)  # at once: a drain would wait for robots' sessions to time out
        for proc in procs:
            proc.wait(timeout=20)


def estimated_capacity(urls: list[str]) -> float | None:
    """What the replicas' own estimators say they can sustain together (GET /capacity), None where they cannot say."""
    import requests

    total = 0.0
    for url in urls:
        try:
            figure = requests.get(url + "/capacity", timeout=5).json().get("capacity_fps")
        except (requests.RequestException, ValueError):
            return None  # a netapp without /capacity (a checkout from before it)
        if figure is None:
            return None
        total += figure
    return total


def robot_processes(robots: int) -> int:
    """How many robot processes carry `robots`: as many robots in each where that can be (a process with fewer
    robots gives each more of its time: on a busy machine that alone would look unfair), at most MAX_PROCESSES."""
    even = [n for n in range(MAX_PROCESSES, MAX_PROCESSES // 2, -1) if robots % n == 0]
    return even[0] if even else min(robots, MAX_PROCESSES)


def run_robots(args, url: str, robots: int, procs: list[subprocess.Popen], urls: list[str]) -> dict:
    with contextlib.ExitStack() as stack:
        return _run_robots(args, url, robots, procs, urls, stack)


def _run_robots(args, url: str, robots: int, procs: list[subprocess.Popen], urls: list[str], stack) -> dict:
    processes = robot_processes(robots)
    per = [robots // processes + (1 if i < robots % processes else 0) for i in range(processes)]
    firsts = [sum(per[:i]) for i in range(processes)]  # each process's first robot's index, for its class
    cmds = [
        [
            *base_cmd(args),
            "--worker",
            "robots",
            "--url",
            url,
            "--robots",
            str(n),
            "--fps",
            str(args.fps),
            "--duration",
            str(args.duration),
            "--transport",
            args.transport,
            "--max-in-flight",
            str(args.max_in_flight),
            "--client",
            args.client,
            "--start",
            args.start,
            "--priority",
            args.priority,
            "--first",
            str(first),
            *(["--deadline-ms", str(args.deadline_ms)] if args.deadline_ms else []),
        ]
        for n, first in zip(per, firsts, strict=True)
    ]
    logs = [stack.enter_context(tempfile.TemporaryFile("w+")) for _ in cmds]
    workers = [
        subprocess.Popen(
            c,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=log,
            text=True,
            preexec_fn=(lambda: os.nice(args.robots_nice)) if args.robots_nice else None,
        )
        for c, log in zip(cmds, logs, strict=True)
    ]
    for worker, log in zip(workers, logs, strict=True):  # each has its frames (and its robots connected)
        if worker.stdout.readline().strip() != READY:
            log.seek(0)
            raise RuntimeError(f"a robot process failed before its start: {log.read()[-2000:]}")
    start_at = time.time() + 0.5
    for worker in workers:
        worker.stdin.write(f"{start_at}\n")
        worker.stdin.close()
    # CPU of the replicas and of the robot processes over the same window, while every robot streams
    measured = [psutil.Process(p.pid) for p in procs] + [psutil.Process(w.pid) for w in workers]
    time.sleep(max(0.0, start_at - time.time()))
    cpu0 = [sum(s.cpu_times()[:2]) for s in measured]
    t0 = time.monotonic()
    time.sleep(0.75 * args.duration)  # the estimate while every robot streams, not while they leave
    cpu = [100 * (sum(s.cpu_times()[:2]) - c) / (time.monotonic() - t0) for s, c in zip(measured, cpu0, strict=True)]
    estimate = estimated_capacity(urls)
    summaries = []
    for w, log in zip(workers, logs, strict=True):
        out = w.stdout.read()
        if w.wait(timeout=args.duration + 120) != 0:
            log.seek(0)
            raise RuntimeError(f"a robot process failed: {log.read()[-2000:]}")
        summaries += json.loads(out.strip().splitlines()[-1])
    summaries.sort(key=lambda s: s["robot"])
    arrivals = [sorted(s.pop("arrivals")) for s in summaries]
    rates = window_rates(arrivals)
    latencies = sorted(v for s in summaries for v in s["latencies_ms"])
    mean = statistics.fmean(rates)
    return {
        "robots": robots,
        "results_per_s": sum(rates),
        "robot_results_per_s": rates,
        "robot_started_s": [s["started_s"] for s in summaries],
        "unserved": [s["failed"] for s in summaries if "failed" in s],
        "first_result_s": max((a[0] - start_at if a else math.inf) for a in arrivals),
        "robot_arrivals_s": [[round(t - start_at, 4) for t in a] for a in arrivals],  # from the common start
        "share_min": min(rates) / mean if mean else 0.0,
        "share_max": max(rates) / mean if mean else 0.0,
        "fairness": min(rates) / max(rates) if max(rates) else 0.0,
        "p50": _pct(latencies, 50),
        "p95": _pct(latencies, 95),
        "sent": sum(s["frames_sent"] for s in summaries),
        "sent_per_s": sum(s["frames_sent"] / s["duration_s"] for s in summaries),
        "lost": sum(s["lost"] for s in summaries),
        "errors": sum(s["errors"] for s in summaries),
        "server_cpu": cpu[: len(procs)],
        "robots_cpu": sum(cpu[len(procs) :]),
        "estimated_capacity": estimate,
        "classes": class_figures(summaries),
    }


def window_rates(arrivals: list[list[float]]) -> list[float]:
    """Each robot's results/s while every robot was getting results: from the last robot's first result to the
    first robot's last one (robots that start together connect over a second or more: a robot's rate over its own
    time would count the seconds it had the netapp to fewer robots). Within it, a robot's rate is its results'
    intervals over their span (counting results would favour the robots whose results open or close the window).
    A robot that got none: 0."""
    if not all(arrivals):
        return [_rate(a) for a in arrivals]
    begin, end = max(a[0] for a in arrivals), min(a[-1] for a in arrivals)
    return [_rate([t for t in a if begin <= t <= end]) for a in arrivals]


def _rate(arrivals: list[float]) -> float:
    """Results per second from result times (sorted): the intervals over their span."""
    if len(arrivals) < 2:
        return 0.0
    return (len(arrivals) - 1) / (arrivals[-1] - arrivals[0])


def class_figures(summaries: list[dict]) -> dict[str, dict]:
    """Per priority class: robots, results/s per robot, share of all results, and the deadline misses: frames
    sent that got no result within the deadline (late, dropped for it, superseded or lost), % of frames sent."""
    total = sum(s["results"] for s in summaries) or 1
    figures = {}
    for name in sorted({s["priority"] for s in summaries}):
        mine = [s for s in summaries if s["priority"] == name]
        sent = sum(s["frames_sent"] for s in mine)
        on_time = sum(s["within_deadline"] for s in mine)
        latencies = sorted(v for s in mine for v in s["latencies_ms"])
        figures[name] = {
            "robots": len(mine),
            "results_per_s_each": statistics.fmean(s["results_per_s"] for s in mine),
            "share": sum(s["results"] for s in mine) / total,
            "within_deadline_per_s": sum(s["within_deadline_per_s"] for s in mine),
            "missed_pct": 100 * (sent - on_time) / sent if sent else 0.0,
            "p50": _pct(latencies, 50),
            "p95": _pct(latencies, 95),
        }
    return figures


def _pct(values: list[float], q: float) -> float | None:
    from netapp.client.stats import percentile

    return percentile(values, q) if values else None


def table(rows: list[dict], maximum: float, fps: float) -> str:
    head = (
        "| variant | replicas | robots | input results/s | frames sent/s | results/s | % of max | % of input "
        "| share min | share max | fairness | p50 ms | p95 ms | lost | errors | replica CPU % | robots CPU % "
        "| estimated capacity results/s | slowest first result s |"
    )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        offered = r["robots"] * fps
        lines.append(
            f"| {r['variant']} | {r['replicas']} | {r['robots']} | {offered:g} | {r['sent_per_s']:.1f} | "
            f"{r['results_per_s']:.1f} | "
            f"{100 * r['results_per_s'] / maximum:.0f} | {100 * r['results_per_s'] / offered:.0f} | "
            f"{r['share_min']:.2f} | {r['share_max']:.2f} | {r['fairness']:.2f} | {r['p50']:.1f} | {r['p95']:.1f} | "
            f"{r['lost']} | {r['errors']} | {' + '.join(f'{c:.0f}' for c in r['server_cpu'])} | "
            f"{r['robots_cpu']:.0f} | "
            f"{'-' if r['estimated_capacity'] is None else round(r['estimated_capacity'], 1)} | "
            f"{r['first_result_s']:.1f} |"
        )
    return "\n".join(lines)


def class_table(rows: list[dict]) -> str:
    """The priority classes of each row (--priorities): who got what, and the deadlines missed."""
    head = (
        "| variant | robots | aggregate results/s | within deadline/s | class | robots in it | results/s each "
        "| share of results | deadline missed % | p50 ms | p95 ms |"
    )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        within = sum(c["within_deadline_per_s"] for c in r["classes"].values())
        for name, c in r["classes"].items():
            lines.append(
                f"| {r['variant']} | {r['robots']} | {r['results_per_s']:.1f} | {within:.1f} | {name} | {c['robots']} "
                f"| {c['results_per_s_each']:.1f} | {100 * c['share']:.0f} % | {c['missed_pct']:.1f} "
                f"| {c['p50']:.0f} | {c['p95']:.0f} |"
            )
    return "\n".join(lines)


def main() -> int:
    shared = ROOT.parent / "shared"
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", default=str(shared / "models" / "yolox_nano.onnx"))
    p.add_argument(
        "--model-args",
        default="",
        help="netapp serve's model flags, given to every replica and to the in-process maximum alike, e.g. "
        "--model-args='--conf 0.0001 --max-detections 20' (with '=': the value starts with a dash; an untrained "
        "export's scores are all under the default 0.3)",
    )
    p.add_argument("--video", default=str(shared / "media" / "pedestrians.avi"))
    p.add_argument("--robots", default="1,4,8,16", help="robot counts (orchestrator) or robots here (worker)")
    p.add_argument("--replicas", default="1,2")
    p.add_argument("--fps", type=float, default=25.0)
    p.add_argument("--duration", type=float, default=15.0, help="seconds each configuration streams")
    p.add_argument("--max-duration", type=float, default=8.0, help="seconds of each in-process maximum run")
    p.add_argument(
        "--transports",
        default="ws",
        help="the robots' transports, side by side: a comma-separated list of ws, http, h264, frames, frames-h264 "
        "and era5g (the unmodified era-5g-client: JPEG at the camera's rate, unpaced)",
    )
    p.add_argument("--transport", default="ws", choices=TRANSPORTS, help=argparse.SUPPRESS)
    p.add_argument(
        "--start",
        default="connected",
        choices=STARTS,
        help="connected: every robot connects, then all stream from one moment; storm: all start at one moment, "
        "each streaming as soon as it is connected",
    )
    p.add_argument("--max-in-flight", type=int, default=2, help="each robot's NetAppClient max_in_flight")
    p.add_argument(
        "--netapp-nice",
        type=int,
        default=0,
        help="run the replicas this much nicer than the robots, so robots sharing the machine are not starved",
    )
    p.add_argument(
        "--robots-nice",
        type=int,
        default=0,
        help="run the robot processes this much nicer than the replicas: robots elsewhere do not take the netapp's "
        "cores, robots on this machine do (unmodified era-5g-clients encode every camera frame)",
    )
    p.add_argument(
        "--clients",
        default="paced",
        help=f"how the robots send, side by side: a comma-separated list of {', '.join(CLIENTS)}",
    )
    p.add_argument("--client", default="paced", choices=tuple(CLIENTS), help=argparse.SUPPRESS)
    p.add_argument(
        "--priorities",
        default=NO_PRIORITIES,
        help="robots' priority classes, side by side: assignments separated by ';', each the classes of robots 0, "
        "1, ... (the last repeats), e.g. 'none;high,low' (none: no robot claims a class). The netapps take a "
        "class token, which the high robots present",
    )
    p.add_argument("--priority", default=NO_PRIORITIES, help=argparse.SUPPRESS)
    p.add_argument("--first", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--deadline-ms", type=float, help="every robot's deadline (its NetAppClient deadline_ms)")
    p.add_argument("--size", dest="size_text", default="640x480")
    p.add_argument(
        "--variants",
        default="netapp=",
        help="server variants run side by side, 'NAME=SERVE ARGS;NAME2=ARGS', e.g. 'spin=--spin-wait;sleep='; "
        "ARGS starting with @DIR run the netapp of the checkout in DIR (a before/after in one run)",
    )
    p.add_argument(
        "--no-balancer",
        action="store_true",
        help="with --replicas 1: robots connect to the replica itself, no HAProxy (a machine without it)",
    )
    p.add_argument("--out", default=str(ROOT / "results"))
    p.add_argument("--worker", choices=("max", "robots"), help=argparse.SUPPRESS)
    p.add_argument("--url", help=argparse.SUPPRESS)
    args = p.parse_args()
    args.size = tuple(int(v) for v in args.size_text.split("x"))
    if args.worker == "max":
        worker_max(args)
        return 0
    if args.worker == "robots":
        args.robots = int(args.robots)
        worker_robots(args)
        return 0
    from tests.support.haproxy import INSTALL_HINT, haproxy_binary

    if args.no_balancer and args.replicas != "1":
        print("--no-balancer runs one replica: give --replicas 1", file=sys.stderr)
        return 2
    try:
        model_config(args)  # the model flags, checked before anything starts
    except ValueError as exc:
        print(f"--model-args: {exc}", file=sys.stderr)
        return 2
    if haproxy_binary() is None and not args.no_balancer:
        print(f"{INSTALL_HINT} (or --replicas 1 --no-balancer)")
        return 2
    out_dir = start_run("robots", args.out, (args.model, args.video))
    if out_dir is None:
        return 2
    maxima = [measure_max(args)]
    print(f"in-process maximum: {maxima[0]:.1f} results/s", file=sys.stderr, flush=True)
    variants = dict(v.partition("=")[::2] for v in args.variants.split(";"))
    clients = args.clients.split(",")
    priorities = args.priorities.split(";")
    transports = args.transports.split(",")
    if unknown := [t for t in transports if t not in TRANSPORTS]:
        print(f"unknown --transports {', '.join(unknown)}: give some of {', '.join(TRANSPORTS)}", file=sys.stderr)
        return 2
    if unknown := [c for c in clients if c not in CLIENTS]:
        print(f"unknown --clients {', '.join(unknown)}: give some of {', '.join(CLIENTS)}", file=sys.stderr)
        return 2
    rows = []
    for count in (int(r) for r in args.replicas.split(",")):
        with contextlib.ExitStack() as stack:
            started = {name: stack.enter_context(replicas(args, count, extra)) for name, extra in variants.items()}
            for robots in (int(n) for n in args.robots.split(",")):
                # interleaved: each robot count on every variant, with every client
                runs = itertools.product(transports, started.items(), clients, priorities)
                for transport, (name, (url, procs, urls)), client, priority in runs:
                    args.transport, args.client, args.priority = transport, client, priority
                    label = ", ".join(
                        [
                            name,
                            *([transport] if len(transports) > 1 else []),
                            *([client] if len(clients) > 1 else []),
                            *([priority] if len(priorities) > 1 else []),
                        ]
                    )
                    row = run_robots(args, url, robots, procs, urls) | {"replicas": count, "variant": label}
                    rows.append(row)
                    print(
                        f"{label}: {count} replica(s), {robots:2} robots: {row['results_per_s']:.1f} results/s, "
                        f"fairness {row['fairness']:.2f}, p50 {row['p50']:.0f} ms, lost {row['lost']}, "
                        f"unserved {len(row['unserved'])}; each robot "
                        f"(results/s, from robot 0): {' '.join(f'{v:.1f}' for v in row['robot_results_per_s'])}",
                        file=sys.stderr,
                        flush=True,
                    )
        maxima.append(measure_max(args))  # again after each replica count: the machine's speed drifts
    maximum = statistics.median(maxima)
    report = (
        f"{table(rows, maximum, args.fps)}\n\nIn-process maximum (decode + detect, one process, back to back): "
        f"{maximum:.1f} results/s (median of {', '.join(f'{m:.1f}' for m in maxima)}, measured before, between "
        "and after). "
        f"Model {Path(args.model).name}{' ' + args.model_args if args.model_args else ''}. "
        f"{args.fps:g} FPS per robot, {args.duration:g} s per configuration, transports {args.transports}, "
        f"start {args.start}, "
        f"{os.cpu_count()} cores.\n"
    )
    if args.priorities != NO_PRIORITIES:
        deadline = f"{args.deadline_ms:g} ms" if args.deadline_ms else "none"
        report += f"\nPriority classes (deadline {deadline}):\n\n{class_table(rows)}\n"
    (out_dir / "table.md").write_text(report)
    (out_dir / "runs.json").write_text(json.dumps({"maxima": maxima, "rows": rows}, indent=1))
    print(report)
    print(f"written: {out_dir}/table.md, runs.json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
