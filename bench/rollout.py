"""What a rollout's shadow costs (docs/rollouts.md): results a second of a saturated netapp with no candidate, and
with a candidate shadowed at the default sample rate and budget, in one run, one table.

    python -m bench.rollout                     # YOLOX-Nano from ../shared, 4 robots, 3 rounds of 15 s per mode
    python -m bench.rollout --quick             # a few seconds: that it runs

A real `netapp serve` per round and mode (interleaved), YOLOX-Nano; the candidate is a re-export of the same model
(the same work as the current one), kept in its shadow for the whole round (never promoted nor rolled back:
--promote-after far away, --min-agreement 0, --max-slowdown 100). `--robots` NetAppClients over `frames`, one frame
in flight each, as fast as results come back: the netapp's capacity. Quote `uptime` with any figure.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import threading
import time
from pathlib import Path

import cv2
import onnx
import requests

from bench.netapps import netapp_process
from netapp.client import NetAppClient

SHARED = Path(__file__).resolve().parent.parent.parent / "shared"
NEVER = str(10**9)  # --promote-after: the shadow lasts the whole round


def stream(url: str, image, seconds: float, robots: int) -> int:
    """Results the robots got in `seconds`, each with one frame in flight."""
    counts = [0] * robots
    stop = threading.Event()

    def robot(i: int) -> None:
        with NetAppClient(url, transport="frames", max_in_flight=1) as client:
            while not stop.is_set():
                client.send(image)
                if next(client.results(timeout=10), None) is None:
                    return
                counts[i] += 1

    threads = [threading.Thread(target=robot, args=(i,), daemon=True) for i in range(robots)]
    for t in threads:
        t.start()
    time.sleep(seconds)  # the measured interval itself, not a synchronisation
    stop.set()
    for t in threads:
        t.join(timeout=15)
    return sum(counts)


def round_of(mode: str, model: str, candidate: str, image, args) -> tuple[float, dict]:
    serve_args: list[str] = []
    if mode == "shadow":
        serve_args += [
            "--candidate",
            candidate,
            "--promote-after",
            NEVER,
            "--min-agreement",
            "0",
            "--max-slowdown",
            "100",
        ]
    with netapp_process(model, serve_args) as (_, port):
        url = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 60
        while mode == "shadow" and not requests.get(url + "/rollout", timeout=5).json()["candidate_loaded"]:
            if time.monotonic() > deadline:
                raise RuntimeError("the candidate did not load")
            time.sleep(0.1)  # polling the rollout's state, with a deadline
        stream(url, image, args.warm_up, args.robots)
        before = requests.get(url + "/rollout", timeout=5).json()
        results = stream(url, image, args.seconds, args.robots)
        after = requests.get(url + "/rollout", timeout=5).json()
    state = {
        "compared": after["frames_compared"] - before["frames_compared"],
        "skipped": sum(after["skipped"].values()) - sum(before["skipped"].values()),
        "phase": after["phase"],
    }
    return results / args.seconds, state


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=str(SHARED / "models" / "yolox_nano.onnx"))
    parser.add_argument("--image", default=str(SHARED / "media" / "ped100.jpg"))
    parser.add_argument("--robots", type=int, default=4)
    parser.add_argument("--seconds", type=float, default=15.0)
    parser.add_argument("--warm-up", type=float, default=3.0)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="one short round: that it runs")
    args = parser.parse_args()
    if args.quick:
        args.seconds, args.warm_up, args.rounds = 2.0, 1.0, 1
    for path in (args.model, args.image):
        if not Path(path).is_file():
            print(f"missing {path}: pass --model / --image (the shared model and media live in ../shared)")
            return
    image = cv2.imread(args.image)
    print(f"load average at the start: {os.getloadavg()}")
    rows: dict[str, list[tuple[float, dict]]] = {"none": [], "shadow": []}
    with tempfile.TemporaryDirectory() as tmp:
        candidate = str(Path(tmp) / "yolox_nano_reexport.onnx")
        onnx.save(onnx.load(args.model), candidate)
        for _ in range(args.rounds):
            for mode in rows:
                rows[mode].append(round_of(mode, args.model, candidate, image, args))
    print(f"load average at the end: {os.getloadavg()}")
    base = statistics.median(r for r, _ in rows["none"])
    print("\n| candidate | results/s (median) | rounds | vs none | frames compared/s | sampled but skipped/s |")
    print("|---|---:|---|---:|---:|---:|")
    for mode, runs in rows.items():
        rates = [r for r, _ in runs]
        median = statistics.median(rates)
        compared = statistics.median(s["compared"] for _, s in runs) / args.seconds
        skipped = statistics.median(s["skipped"] for _, s in runs) / args.seconds
        shown = ", ".join(f"{r:.1f}" for r in rates)
        print(
            f"| {mode} | {median:.1f} | {shown} | {100 * (median / base - 1):+.1f} % | {compared:.2f} | {skipped:.2f} |"
        )


if __name__ == "__main__":
    main()
