"""The tracking netapp on the pedestrian video: id switches per 100 frames with and without a move between
netapps (a SIGKILL mid-stream, then another netapp), and what checkpointing the tracker's state costs.

    python -m bench.tracking --model M [--video V] [--frames 341] [--move-at 170] [--repeat 1] [--json]

Each scenario streams the same frames with their capture times as timestamps, keeping two frames in flight (no
frame dropped: tracking quality does not depend on the machine's speed); scenarios are interleaved when repeated,
and the table shows medians. An id switch: an object (its box overlapping one of the previous result by half or
more) seen under another id than in the previous result; no ground truth needed.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import threading
import time
from pathlib import Path

import cv2

from bench.robot import robot_jpeg
from netapp.client import NetAppClient
from netapp.serve_process import NetAppProcess
from netapp.track.compare import id_switches

ROOT = Path(__file__).resolve().parent.parent
FRAME_NS = 40_000_000  # 25 fps capture times

# name -> (checkpoint every N results, move mid-stream)
SCENARIOS = {
    "no move, no checkpoints": (0, False),
    "no move, checkpoint every result": (1, False),
    "no move, checkpoint every 10": (10, False),
    "move, state restored (every result)": (1, True),
    "move, state restored (every 10)": (10, True),
    "move, no state": (0, True),
}


def jpegs(video: str, count: int, size: tuple[int, int]) -> list[bytes]:
    capture = cv2.VideoCapture(video)
    out = []
    while len(out) < count:
        ok, frame = capture.read()
        if not ok:
            break
        out.append(robot_jpeg(cv2.resize(frame, size)))
    capture.release()
    return out


def netapp(model: str) -> NetAppProcess:
    return NetAppProcess("--model", model, "--processor", "object-tracking").start()


def state_cost(state: dict, repeat: int = 200) -> dict:
    """Milliseconds to serialise a checkpoint (on the inference thread, per checkpoint) and to restore it."""
    from netapp.models.detector import DetectorConfig
    from netapp.sdk.session_state import dump_state, load_state
    from netapp.track.processor import TrackingDetector

    processor = TrackingDetector(DetectorConfig("unused.onnx"))  # the state needs no model
    tracker = load_state(processor, state)
    text = dump_state(processor, tracker)

    def ms(fn) -> float:
        times = []
        for _ in range(repeat):
            t = time.perf_counter()
            fn()
            times.append((time.perf_counter() - t) * 1e3)
        return statistics.median(times)

    return {
        "tracks": len(state["tracks"]),
        "bytes": len(text),
        "serialise_ms": ms(lambda: json.loads(dump_state(processor, tracker))),  # what each checkpoint costs
        "restore_ms": ms(lambda: load_state(processor, text)),
    }


def run(frames: list[bytes], url: str, every: int, move_to: NetAppProcess | None, move_at: int, killed) -> dict:
    free = threading.Semaphore(2)
    results: dict[int, dict] = {}
    sizes: list[int] = []
    server_ms: list[float] = []  # the model, the tracker and the checkpoint of each result, on the netapp
    largest: list[dict] = [{}]

    def on_result(result):
        if "state" in result.message:
            sizes.append(len(json.dumps(result.message["state"], separators=(",", ":"))))
            if sizes[-1] == max(sizes):
                largest[0] = result.message["state"]
        results[result.timestamp] = result.detections
        server_ms.append((result.message["timestamp_after_process"] - result.message["timestamp_before_process"]) / 1e6)
        free.release()

    client = NetAppClient(
        url,
        "ws",
        checkpoint_every=every,
        max_in_flight=2,
        on_result=on_result,
        on_error=lambda message: free.release(),
        result_timeout_s=5,
    )
    client.connect()
    started = time.perf_counter()
    moved_s = 0.0
    try:
        for i, jpeg in enumerate(frames):
            if move_to is not None and i == move_at:
                client.wait_idle(10)
                killed()  # the netapp dies mid-stream ...
                t = time.perf_counter()
                client.switch_url(move_to.url)  # ... and the robot is sent to another one
                moved_s = time.perf_counter() - t
                free = threading.Semaphore(2)  # frames in flight to the dead netapp are lost
            if not free.acquire(timeout=10):
                free = threading.Semaphore(2)
            client.send(jpeg, timestamp=(i + 1) * FRAME_NS)
        client.wait_idle(10)
        elapsed = time.perf_counter() - started - moved_s
    finally:
        client.close()
    ordered = [results[t] for t in sorted(results)]
    return {
        "results": len(ordered),
        "results_per_s": len(ordered) / elapsed,
        "server_ms": statistics.median(server_ms),
        "id_switches_per_100": 100 * id_switches(ordered) / max(1, len(ordered)),
        "checkpoint_bytes": statistics.median(sizes) if sizes else None,
        "checkpoint_bytes_max": max(sizes) if sizes else None,
        "restores": client.stats.restores,
        "move_s": moved_s,
        "largest_state": largest[0],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=str(ROOT.parent / "shared" / "models" / "yolox_nano.onnx"))
    parser.add_argument("--video", default=str(ROOT.parent / "shared" / "media" / "pedestrians.avi"))
    parser.add_argument("--frames", type=int, default=341)
    parser.add_argument("--move-at", type=int, default=170)
    parser.add_argument("--size", default="640x360")
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--scenarios", help="comma-separated scenario names (default: all)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    frames = jpegs(args.video, args.frames, size)
    print(f"{len(frames)} frames of {args.video} at {args.size}", file=sys.stderr)
    steady = netapp(args.model).wait_ready()
    chosen = {n: SCENARIOS[n] for n in args.scenarios.split(",")} if args.scenarios else SCENARIOS
    rows: dict[str, list[dict]] = {name: [] for name in chosen}
    try:
        for r in range(args.repeat):
            for name, (every, move) in chosen.items():
                doomed = netapp(args.model).wait_ready() if move else None
                url = doomed.url if doomed else steady.url
                row = run(frames, url, every, steady if move else None, args.move_at, lambda d=doomed: d.kill())
                rows[name].append(row)
                shown = {k: v for k, v in row.items() if k != "largest_state"}
                print(f"[{r + 1}/{args.repeat}] {name}: {json.dumps(shown)}", file=sys.stderr)
    finally:
        steady.kill()
    states = [row.pop("largest_state") for runs in rows.values() for row in runs]
    largest = max(states, key=lambda s: len(json.dumps(s)))
    cost = state_cost(largest) if largest else None
    table = {name: {k: _median([row[k] for row in runs]) for k in runs[0]} for name, runs in rows.items()}
    if args.json:
        print(json.dumps({"scenarios": table, "checkpoint_cost": cost}, indent=1))
        return 0
    base = next(iter(table.values()))["results_per_s"]
    print(
        "| scenario | results | id switches / 100 frames | checkpoint bytes (median, max) | netapp ms per frame "
        "| results/s | vs first |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    for name, row in table.items():
        cp = f"{row['checkpoint_bytes']:.0f}, {row['checkpoint_bytes_max']:.0f}" if row["checkpoint_bytes"] else "-"
        print(
            f"| {name} | {row['results']:.0f} | {row['id_switches_per_100']:.2f} | {cp} | {row['server_ms']:.1f} | "
            f"{row['results_per_s']:.1f} | {row['results_per_s'] / base:.2f} |"
        )
    if cost:
        print(
            f"\nThe largest checkpoint ({cost['tracks']} tracks, {cost['bytes']} bytes): serialised in "
            f"{cost['serialise_ms']:.2f} ms on the inference thread, restored in {cost['restore_ms']:.2f} ms "
            "(medians of 200)."
        )
    return 0


def _median(values):
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


if __name__ == "__main__":
    raise SystemExit(main())
