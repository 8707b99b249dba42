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
import time
from pathlib import Path

import psutil

from bench.netapps import start_run
from bench.robots_figures import class_figures, class_table, pct, table, window_rates
from bench.robots_worker import (
    CLASS_TOKEN,
    CLIENTS,
    NO_PRIORITIES,
    READY,
    STARTS,
    TRANSPORTS,
    model_config,
    worker_max,
    worker_robots,
)
from netapp.serve_process import free_port, serve_command, wait_http_ok
from netapp.server.access import token_digest

ROOT = Path(__file__).resolve().parent.parent

MAX_PROCESSES = 4  # robot processes; robots beyond that share a process, each on its own threads


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
        "p50": pct(latencies, 50),
        "p95": pct(latencies, 95),
        "sent": sum(s["frames_sent"] for s in summaries),
        "sent_per_s": sum(s["frames_sent"] / s["duration_s"] for s in summaries),
        "lost": sum(s["lost"] for s in summaries),
        "errors": sum(s["errors"] for s in summaries),
        "server_cpu": cpu[: len(procs)],
        "robots_cpu": sum(cpu[len(procs) :]),
        "estimated_capacity": estimate,
        "classes": class_figures(summaries),
    }


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
