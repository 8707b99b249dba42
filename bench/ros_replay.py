"""A ROS 2 bag replayed through a netapp at its recorded rate: the share of frames answered (issue 23's goal: a
1,000-frame 720p bag, >= 99 % over loopback).

    python -m bench.ros_replay                       # 1000 frames, 1280x720 JPEG CompressedImage, 10 FPS, ws
    python -m bench.ros_replay --frames 200 --fps 20 --transport http

The bag (ROS 2, MCAP storage) is made first from `../shared/media/pedestrians.avi` resampled to `--fps` and resized
to `--size`, stamped at the recorded rate; the netapp (`netapp serve` with the shared YOLOX-Nano) runs as its own
process; the replay is `netapp stream`'s (`BagSource` at rate 1, newest frame wins). Prints one JSON line (also in
results/ros-replay-<time>/summary.json) with the machine's load average before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path

from bench.netapps import netapp_process, start_run
from netapp.client import NetAppClient
from netapp.client.streaming import parse_size, stream
from netapp.ros.bag_writer import video_to_bag
from netapp.ros.bags import BagSource

SHARED = Path("../shared")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=str(SHARED / "models/yolox_nano.onnx"))
    parser.add_argument("--video", default=str(SHARED / "media/pedestrians.avi"))
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--fps", type=float, default=10.0, help="the bag's recorded rate (default 10)")
    parser.add_argument("--size", default="1280x720")
    parser.add_argument("--transport", default="ws")
    parser.add_argument("--out", default="results")
    args = parser.parse_args()
    out_dir = start_run("ros-replay", args.out, [args.model, args.video])
    if out_dir is None:
        return
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "camera"
        video_to_bag(args.video, bag, args.frames, args.fps, parse_size(args.size))
        with netapp_process(args.model):
            pass  # the first start loads the model from disk into the page cache; the timed run starts warm
        load_before = os.getloadavg()
        with netapp_process(args.model) as (_, port):
            source = BagSource(str(bag), rate=1.0)
            with NetAppClient(f"http://127.0.0.1:{port}", transport=args.transport) as client:
                summary = stream(client, source, args.fps, float("inf"))
        load_after = os.getloadavg()
    recorded_s = (args.frames - 1) / args.fps
    report = {
        "frames": args.frames,
        "size": args.size,
        "recorded_fps": args.fps,
        "transport": args.transport,
        "recorded_s": round(recorded_s, 2),
        "replay_s": summary["duration_s"],
        "results": summary["results"],
        "answered": round(summary["results"] / args.frames, 4),
        "dropped": summary["dropped"],
        "latency_ms": summary["latency_ms"],
        "latency_breakdown_ms": summary["latency_breakdown_ms"],
        "cpus": os.cpu_count(),
        "load_before": [round(v, 2) for v in load_before],
        "load_after": [round(v, 2) for v in load_after],
    }
    (out_dir / "summary.json").write_text(json.dumps(report, indent=2))
    print(json.dumps(report))


if __name__ == "__main__":
    main()
