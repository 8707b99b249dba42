"""Frames through a broker (docs/broker.md#frames-through-a-broker) against `frames`, side by side in one run: one
`netapp serve` (YOLOX-Nano) that takes frames on its WebSocket and from RabbitMQ's and Mosquitto's work queues
(`--consume`), robots streaming pre-encoded 1280x720 JPEG of the shared video in this process:

- latency: one robot at each FPS on each route, the routes taking turns (`--rounds` turns each, so the machine's drift
  falls on every route alike): p50 and p95 of its results' latency, and what the broker adds over `frames` on
  loopback;
- fair share: four robots at 25 FPS through one broker (the model the bottleneck): each robot's results per second,
  and min/max;
- replicas (`--part replicas`): the same four robots against one netapp and then two netapps on the one work queue
  (the same `?netapp=`), each netapp held to a CPU of its own (`taskset`, as a pod's CPU limit of 1) with
  onnxruntime on one thread, one lane and no prepare thread (`--threads 1 --lanes 1 --prepare-threads 0`): what a
  second replica adds when the model is the bottleneck, not what a second process can take from a first that
  already spread over the machine's cores; results per second of all robots together, and the ratio. The robots and
  the broker run on any CPU, so on a 2-core machine they take their share from the replicas.

    benchlock wpy -m bench.broker_channel --duration 20
    benchlock wpy -m bench.broker_channel --part replicas --duration 20 [--size 640x360]
"""

from __future__ import annotations

import argparse
import os
import threading
import time
from contextlib import ExitStack

import psutil

from bench.netapps import netapp_process
from bench.robot import jpeg_frames
from netapp.client import NetAppClient
from netapp.client.stats import percentile
from tests.support.brokers import Mosquitto, RabbitMQ

SIZE = (1280, 720)


def load() -> str:
    return "load average " + ", ".join(f"{x:.2f}" for x in os.getloadavg())


def robot(url: str, frames: list[bytes], fps: float, duration_s: float, out: dict, name: str, **options) -> None:
    """Stream `frames` (cycled) at `fps` for `duration_s`; `out[name]`: its latencies (ms) and results."""
    with NetAppClient(url, robot_id=name, **options) as client:
        start, n = time.monotonic(), 0
        while time.monotonic() - start < duration_s:
            client.send(frames[n % len(frames)])
            n += 1
            time.sleep(max(0.0, start + n / fps - time.monotonic()))
        time.sleep(2.0)  # the last results
        parts = {part: list(values) for part, values in client.stats.parts_ms.items()}
        out[name] = {"latencies": list(client.stats.latencies_ms), "parts": parts, "sent": n, "duration_s": duration_s}


def latency_rows(
    routes: dict[str, tuple[str, dict]], frames: list[bytes], fps_list, duration_s: float, rounds: int
) -> list[tuple]:
    """Per FPS and route: results, p50, p95, added p50 and p95 over the first route, and the parts' p50. The routes
    take turns, `rounds` of `duration_s / rounds` each."""
    rows = []
    for fps in fps_list:
        found: dict[str, dict] = {route: {"latencies": [], "parts": {}} for route in routes}
        for _ in range(rounds):
            for route, (url, options) in routes.items():
                out: dict = {}
                robot(url, frames, fps, duration_s / rounds, out, "latency", **options)
                found[route]["latencies"] += out["latency"]["latencies"]
                for part, values in out["latency"]["parts"].items():
                    found[route]["parts"].setdefault(part, []).extend(values)
        base = None
        for route, got in found.items():
            lat, parts_ms = got["latencies"], got["parts"]
            # each result's time around the model (uplink, queue, downlink): the model's own swings left out
            up, queue, down = (parts_ms[p] for p in ("uplink_ms", "queue_ms", "downlink_ms"))
            around = [a + b + c for a, b, c in zip(up, queue, down, strict=True)]
            p50, p95, around_p50 = percentile(lat, 50), percentile(lat, 95), percentile(around, 50)
            base = base or (p50, p95, around_p50)
            parts = {part.removesuffix("_ms"): percentile(v, 50) for part, v in parts_ms.items()}
            parts["added_around"] = around_p50 - base[2]
            rows.append((route, fps, len(lat), p50, p95, p50 - base[0], p95 - base[1], parts))
    return rows


def fair_share(url: str, frames: list[bytes], duration_s: float) -> dict[str, float]:
    out: dict = {}
    threads = [
        threading.Thread(target=robot, args=(url, frames, 25.0, duration_s, out, f"robot-{i}")) for i in range(4)
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return {name: len(o["latencies"]) / o["duration_s"] for name, o in sorted(out.items())}


ONE_CORE = ["--threads", "1", "--lanes", "1", "--prepare-threads", "0"]


def cpu_s(processes: list[psutil.Process], tree: bool = True) -> float:
    """CPU seconds (user and system, all threads) the processes (and, with `tree`, their descendants) have used."""
    every = [q for p in processes for q in (p, *(p.children(recursive=True) if tree else ()))]
    return sum(sum(q.cpu_times()[:2]) for q in every)


def cpu_now(replicas: list[psutil.Process], broker: psutil.Process) -> tuple[float, float, float]:
    """CPU seconds so far of the replicas, of the robots (this process's own threads: the broker and the replicas are
    its children, counted apart) and of the broker."""
    return cpu_s(replicas), cpu_s([psutil.Process()], tree=False), cpu_s([broker])


def replicas(
    model: str, url: str, broker_pid: int, frames: list[bytes], duration_s: float
) -> dict[int, tuple[float, float, float, float]]:
    """Four robots at 25 FPS through `url`'s work queue, served by one netapp and then by two on the same queue
    (each on a CPU of its own): by replicas, results per second of all four together, and the CPU (cores, while the
    robots streamed) that the replicas, the robots and the broker used."""
    found, cpus, broker = {}, os.cpu_count() or 1, psutil.Process(broker_pid)
    for count in (1, 2):
        with ExitStack() as netapps:
            servers = [
                netapps.enter_context(netapp_process(model, ["--consume", url, *ONE_CORE], cpus=str(replica % cpus)))[0]
                for replica in range(count)
            ]
            processes = [psutil.Process(server.pid) for server in servers]
            out: dict = {}
            threads = [
                threading.Thread(target=robot, args=(url, frames, 25.0, duration_s, out, f"robot-{i}"))
                for i in range(4)
            ]
            started, before = time.monotonic(), cpu_now(processes, broker)
            for thread in threads:
                thread.start()
            for thread in threads:
                thread.join()
            elapsed = time.monotonic() - started
            cores = [(after - was) / elapsed for after, was in zip(cpu_now(processes, broker), before, strict=True)]
        found[count] = (sum(len(o["latencies"]) for o in out.values()) / duration_s, *cores)
    return found


def main(args: argparse.Namespace) -> None:
    frames = jpeg_frames(args.video, 25.0, args.size, 50)
    print(load(), f"; {len(frames)} frames of {sum(map(len, frames)) / len(frames) / 1024:.0f} KB on average")
    with RabbitMQ() as rabbit, Mosquitto() as mosquitto:
        amqp = f"{rabbit.url}?netapp=bench"
        mqtt = f"{mosquitto.url}/?netapp=bench"
        if args.part == "replicas":
            found = {
                name: replicas(args.model, url, pid, frames, args.duration)
                for name, url, pid in (("RabbitMQ", amqp, rabbit.pid), ("MQTT 5", mqtt, mosquitto.pid))
            }
            print(load())
            print(
                "\n| broker | one netapp: results/s (its CPU, cores) | two netapps on one queue: results/s (their CPU) "
                "| ratio | results per replica core, two vs one | beside two replicas: robots, broker (cores) |\n"
                "|---|---:|---:|---:|---:|---:|"
            )
            for name, got in found.items():
                (one, one_cores, *_), (two, two_cores, robots, broker) = got[1], got[2]
                per_core = (two / two_cores) / (one / one_cores)
                print(
                    f"| {name} | {one:.1f} ({one_cores:.2f}) | {two:.1f} ({two_cores:.2f}) | {two / one:.2f}x "
                    f"| {per_core:.2f}x | {robots:.2f}, {broker:.2f} |"
                )
            return
        serve_args = ["--consume", amqp, "--consume", mqtt]
        with netapp_process(args.model, serve_args) as (_, port):
            routes = {
                "frames (WebSocket)": (f"http://127.0.0.1:{port}", {"transport": "frames"}),
                "RabbitMQ": (amqp, {}),
                "MQTT": (mqtt, {}),
            }
            rows = latency_rows(routes, frames, args.fps, args.duration, args.rounds)
            print(load())
            brokers = {name: url for name, (url, _) in routes.items() if name != "frames (WebSocket)"}
            shares = {name: fair_share(url, frames, args.duration) for name, url in brokers.items()}
            print(load())
    print("\n| route | FPS | results | p50 ms | p95 ms | added p50 ms | added p95 ms |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for route, fps, count, p50, p95, a50, a95, _ in rows:
        print(f"| {route} | {fps:g} | {count} | {p50:.1f} | {p95:.1f} | {a50:+.1f} | {a95:+.1f} |")
    print(
        "\n| route | FPS | uplink p50 ms | queue p50 ms | inference p50 ms | downlink p50 ms "
        "| added p50 ms, the model's time out |\n|---|---:|---:|---:|---:|---:|---:|"
    )
    for route, fps, *_, parts in rows:  # where the time goes: the results' own breakdown (netapp.client.timing)
        cells = " | ".join(f"{parts.get(p, float('nan')):.1f}" for p in ("uplink", "queue", "inference", "downlink"))
        print(f"| {route} | {fps:g} | {cells} | {parts['added_around']:+.1f} |")
    print("\n| broker | four robots at 25 FPS: results/s each | fair share (min/max) |\n|---|---|---:|")
    for name, rates in shares.items():
        values = list(rates.values())
        each = ", ".join(f"{v:.1f}" for v in values)
        print(f"| {name} | {each} | {min(values) / max(values):.2f} |")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="../shared/models/yolox_nano.onnx")
    parser.add_argument("--video", default="../shared/media/pedestrians.avi")
    parser.add_argument("--fps", type=lambda s: [float(x) for x in s.split(",")], default=[10.0, 25.0])
    parser.add_argument("--duration", type=float, default=20.0, help="seconds per route and FPS (latency), per part")
    parser.add_argument("--rounds", type=int, default=3, help="turns the latency routes take, duration/rounds each")
    parser.add_argument(
        "--size",
        type=lambda s: tuple(int(x) for x in s.split("x")),
        default=SIZE,
        help="the frames' WxH (default 1280x720; smaller leaves the model more of the CPU)",
    )
    parser.add_argument("--part", choices=("latency", "replicas"), default="latency", help="latency: with fair share")
    main(parser.parse_args())
