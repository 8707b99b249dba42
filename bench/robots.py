"""Many robots against 1 and 2 replicas behind a real balancer, side by side in one run.

    python -m bench.robots                                   # 1, 4, 8, 16 robots at 25 FPS; 1 and 2 replicas; 15 s
    python -m bench.robots --robots 8 --replicas 1 --duration 10 --variants 'spin=--spin-wait;sleep='

Each replica is a `netapp serve` process (the shared YOLOX-Nano, the hard limit off so every robot is served);
HAProxy (Debian's package: TCP, round robin per connection, like a Service) stands in front of them; robots are
NetAppClients on Socket.IO, spread over up to 4 robot processes, each streaming pre-encoded 640x480 JPEG frames of
../shared/media/pedestrians.avi at the input rate (`--transport h264`: BGR frames, each robot encoding them live).
The in-process maximum (decode + detect, back to back, one process) is measured in the same run, before and
after, and the table is against its median.

Columns: aggregate results/s and its % of the in-process maximum (of the input rate where robots ask for less);
each robot's share of the aggregate (its results/s over the mean: min and max) and fairness (min/max); latency
p50/p95 over every result; frames lost (sent, then neither a result nor an error came back); replica CPU %; and
what the replicas' own capacity estimators said at the end (GET /capacity, summed), beside what they delivered.
Writes results/robots-<time>/table.md and runs.json.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import os
import signal
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

import psutil

from bench.netapps import start_run
from netapp.serve_process import free_port, serve_command, wait_http_ok
from netapp.server.access import token_digest

ROOT = Path(__file__).resolve().parent.parent

MAX_PROCESSES = 4  # robot processes; robots beyond that share a process, each on its own threads


def jpeg_frames(video: str, size: tuple[int, int], count: int, fps: float = 25.0) -> list[bytes]:
    import cv2

    return [
        cv2.imencode(".jpg", f, [cv2.IMWRITE_JPEG_QUALITY, 85])[1].tobytes()
        for f in raw_frames(video, size, count, fps)
    ]


def raw_frames(video: str, size: tuple[int, int], count: int, fps: float = 25.0) -> list:
    """Decoded BGR frames (what the H.264 transport encodes live)."""
    from netapp.client.sources import open_source

    return list(itertools.islice(open_source(video, fps, size), count))


# -- worker modes (run as subprocesses) -----------------------------------------------------------------------------


def worker_max(args) -> None:
    """The in-process maximum: decode and detect pre-encoded frames back to back for `duration` seconds."""
    from netapp.detect import Detector, DetectorConfig
    from netapp.server.decoding.jpeg import decode_jpeg

    detector = Detector(DetectorConfig(args.model))
    detector.load()
    frames = jpeg_frames(args.video, args.size, 100)
    start = time.monotonic()
    done = 0
    while time.monotonic() - start < args.duration:
        detector.detect(decode_jpeg(frames[done % len(frames)]))
        done += 1
    print(json.dumps({"results_per_s": done / (time.monotonic() - start)}))


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


def worker_robots(args) -> None:
    """`--robots` robots in this process, each a NetAppClient on its own thread, streaming at `--fps`."""
    from netapp.client import NetAppClient
    from netapp.client.streaming import stream

    # Pre-encoded JPEG; H.264 encodes BGR frames live on each robot.
    frames = (raw_frames if args.transport == "h264" else jpeg_frames)(args.video, args.size, 100)
    summaries: list[dict] = []
    lock = threading.Lock()
    start_at = args.start_at  # every process's robots start together, on the wall clock

    def robot(i: int) -> None:
        priority = robot_class(args.priority, args.first + i)
        session = {"args": {"priority": priority}} if priority else {}
        if priority == "high":
            session["token"] = CLASS_TOKEN
        options = client_options(args) | session | {"deadline_ms": args.deadline_ms}
        with NetAppClient(args.url, transport=args.transport, robot_id=f"robot-{i}", **options) as client:
            time.sleep(max(0.0, start_at - time.time()))  # the common start: pacing, not synchronisation
            offset = (i * 7) % len(frames)
            summary = stream(client, itertools.cycle(frames[offset:] + frames[:offset]), args.fps, args.duration)
            summary["latencies_ms"] = list(client.stats.latencies_ms)
            summary["priority"] = priority or "normal"
            with lock:
                summaries.append(summary)

    threads = [threading.Thread(target=robot, args=(i,)) for i in range(args.robots)]
    for t in threads:
        t.start()
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
        "--video",
        args.video,
        "--size",
        args.size_text,
    ]


def measure_max(args) -> float:
    return run_json([*base_cmd(args), "--worker", "max", "--duration", str(args.max_duration)], 300)["results_per_s"]


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


def run_robots(args, url: str, robots: int, procs: list[subprocess.Popen], urls: list[str]) -> dict:
    processes = min(robots, MAX_PROCESSES)
    per = [robots // processes + (1 if i < robots % processes else 0) for i in range(processes)]
    start_at = time.time() + 3.0 + 0.3 * robots  # time for every robot to connect first
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
            "--start-at",
            str(start_at),
            "--priority",
            args.priority,
            "--first",
            str(first),
            *(["--deadline-ms", str(args.deadline_ms)] if args.deadline_ms else []),
        ]
        for n, first in zip(per, firsts, strict=True)
    ]
    workers = [subprocess.Popen(c, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for c in cmds]
    # CPU of the replicas and of the robot processes over the same window, while every robot streams
    measured = [psutil.Process(p.pid) for p in procs] + [psutil.Process(w.pid) for w in workers]
    time.sleep(max(0.0, start_at - time.time()))
    cpu0 = [sum(s.cpu_times()[:2]) for s in measured]
    t0 = time.monotonic()
    time.sleep(0.75 * args.duration)  # the estimate while every robot streams, not while they leave
    cpu = [100 * (sum(s.cpu_times()[:2]) - c) / (time.monotonic() - t0) for s, c in zip(measured, cpu0, strict=True)]
    estimate = estimated_capacity(urls)
    summaries = []
    for w in workers:
        out, err = w.communicate(timeout=args.duration + 120)
        if w.returncode != 0:
            raise RuntimeError(f"a robot process failed: {err[-2000:]}")
        summaries += json.loads(out.strip().splitlines()[-1])
    rates = [s["results_per_s"] for s in summaries]
    latencies = sorted(v for s in summaries for v in s["latencies_ms"])
    mean = statistics.fmean(rates)
    return {
        "robots": robots,
        "results_per_s": sum(rates),
        "robot_results_per_s": rates,
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
        "| estimated capacity results/s |"
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
            f"{'-' if r['estimated_capacity'] is None else round(r['estimated_capacity'], 1)} |"
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
    p.add_argument("--video", default=str(shared / "media" / "pedestrians.avi"))
    p.add_argument("--robots", default="1,4,8,16", help="robot counts (orchestrator) or robots here (worker)")
    p.add_argument("--replicas", default="1,2")
    p.add_argument("--fps", type=float, default=25.0)
    p.add_argument("--duration", type=float, default=15.0, help="seconds each configuration streams")
    p.add_argument("--max-duration", type=float, default=8.0, help="seconds of each in-process maximum run")
    p.add_argument("--transport", default="ws", choices=("ws", "http", "h264"))
    p.add_argument("--max-in-flight", type=int, default=2, help="each robot's NetAppClient max_in_flight")
    p.add_argument(
        "--netapp-nice",
        type=int,
        default=0,
        help="run the replicas this much nicer than the robots, so robots sharing the machine are not starved",
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
    p.add_argument("--out", default=str(ROOT / "results"))
    p.add_argument("--worker", choices=("max", "robots"), help=argparse.SUPPRESS)
    p.add_argument("--url", help=argparse.SUPPRESS)
    p.add_argument("--start-at", type=float, default=0.0, help=argparse.SUPPRESS)
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

    if haproxy_binary() is None:
        print(INSTALL_HINT)
        return 2
    out_dir = start_run("robots", args.out, (args.model, args.video))
    if out_dir is None:
        return 2
    maxima = [measure_max(args)]
    print(f"in-process maximum: {maxima[0]:.1f} results/s", file=sys.stderr, flush=True)
    variants = dict(v.partition("=")[::2] for v in args.variants.split(";"))
    clients = args.clients.split(",")
    priorities = args.priorities.split(";")
    if unknown := [c for c in clients if c not in CLIENTS]:
        print(f"unknown --clients {', '.join(unknown)}: give some of {', '.join(CLIENTS)}", file=sys.stderr)
        return 2
    rows = []
    for count in (int(r) for r in args.replicas.split(",")):
        with contextlib.ExitStack() as stack:
            started = {name: stack.enter_context(replicas(args, count, extra)) for name, extra in variants.items()}
            for robots in (int(n) for n in args.robots.split(",")):
                # interleaved: each robot count on every variant, with every client
                runs = itertools.product(started.items(), clients, priorities)
                for (name, (url, procs, urls)), client, priority in runs:
                    args.client, args.priority = client, priority
                    label = ", ".join(
                        [name, *([client] if len(clients) > 1 else []), *([priority] if len(priorities) > 1 else [])]
                    )
                    row = run_robots(args, url, robots, procs, urls) | {"replicas": count, "variant": label}
                    rows.append(row)
                    print(
                        f"{label}: {count} replica(s), {robots:2} robots: {row['results_per_s']:.1f} results/s, "
                        f"fairness {row['fairness']:.2f}, p50 {row['p50']:.0f} ms, lost {row['lost']}",
                        file=sys.stderr,
                        flush=True,
                    )
        maxima.append(measure_max(args))  # again after each replica count: the machine's speed drifts
    maximum = statistics.median(maxima)
    report = (
        f"{table(rows, maximum, args.fps)}\n\nIn-process maximum (decode + detect, one process, back to back): "
        f"{maximum:.1f} results/s (median of {', '.join(f'{m:.1f}' for m in maxima)}, measured before, between "
        "and after). "
        f"{args.fps:g} FPS per robot, {args.duration:g} s per configuration, transport {args.transport}, "
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
