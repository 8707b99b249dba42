"""A ROS 2 bag replayed through a netapp at its recorded rate: the share of frames answered (issue 23's goal: a
1,000-frame 720p bag, >= 99 % over loopback and through the emulated thin uplink with the adaptive sending).

    python -m bench.ros_replay                              # 1000 frames, 1280x720 JPEG, 10 FPS; loopback and 1.5
    python -m bench.ros_replay --uplinks 1.5 --modes auto,off,full
    python -m bench.ros_replay --frames 200 --fps 20 --uplinks loopback --transport http
    python -m bench.ros_replay --quick                      # a few frames a row (the smoke test)

The bag (ROS 2, MCAP storage) is made first from `../shared/media/pedestrians.avi` resampled to `--fps` and resized
to `--size`, stamped at the recorded rate; the netapp (`netapp serve` with the shared YOLOX-Nano) runs as its own
process; the replay is `netapp stream`'s (`BagSource` at rate 1, newest frame wins). Rows: each uplink (`loopback`,
or Mbit/s through the link emulator with the 5G profile's delay and jitter, as bench/uplink.py's rows) times each
way of sending (bench/uplink.py's modes: `auto` adapts, `off` sends every frame fitted to the model, `full` is `off`
with `--full-frames`, the recorded JPEG as it is). Prints a table (also results/ros-replay-<time>/table.md, and
summary.json) with the machine's load average before and after each row.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any

from bench.netapps import netapp_process, start_run
from bench.uplink import MODES, thin_uplink
from netapp.apps.streaming import parse_size, stream
from netapp.client import NetAppClient
from netapp.client.sending_args import add_sending_arguments, sending_options
from netapp.ros.bag_writer import video_to_bag
from netapp.ros.bags import BagSource

SHARED = Path("../shared")
LOOPBACK = "loopback"


def client_options(mode: str) -> dict[str, Any]:
    """`NetAppClient` keywords for one of bench/uplink.py's modes, read as `netapp stream` reads its options."""
    parser = argparse.ArgumentParser()
    add_sending_arguments(parser)
    return sending_options(parser.parse_args(MODES[mode]))


def replay(bag: Path, port: int, uplink: str, mode: str, args: argparse.Namespace) -> dict[str, Any]:
    """One row: the bag at its recorded rate to the netapp on `port`, over loopback or a thin uplink."""
    load_before = os.getloadavg()
    with contextlib.ExitStack() as stack:
        host, link_port, link = "127.0.0.1", port, LOOPBACK
        if uplink != LOOPBACK:
            emulator = thin_uplink(port, float(uplink), args.link_mode)
            host, link_port = stack.enter_context(emulator)
            link = emulator.mode  # netns or userspace, as --link-mode chose
        client = NetAppClient(f"http://{host}:{link_port}", transport=args.transport, **client_options(mode))
        with client:
            summary = stream(client, BagSource(str(bag), rate=1.0), args.fps, float("inf"))
            adapt = client.adapt_report()
    latency = summary["latency_ms"]
    return {
        "uplink": uplink,
        "mode": mode,
        "link": link,
        "frames": args.frames,
        "recorded_s": round((args.frames - 1) / args.fps, 2),
        "replay_s": summary["duration_s"],
        "results": summary["results"],
        "answered": round(summary["results"] / args.frames, 4),
        "dropped": summary["dropped"],
        "latency_ms": latency,
        "kb_per_frame": round(summary["bytes_per_frame"] / 1000, 1),
        "settings": adapt["settings"] if adapt else None,
        "skipped_for_rate": adapt["skipped_for_rate"] if adapt else 0,
        "latency_breakdown_ms": summary["latency_breakdown_ms"],
        "load_before": [round(v, 2) for v in load_before],
        "load_after": [round(v, 2) for v in os.getloadavg()],
    }


def table(rows: list[dict[str, Any]]) -> str:
    out = [
        "| uplink | sending | answered | replayed / recorded | latency p50 / p95 ms | KB per frame | last settings "
        "| load before / after |",
        "|---|---|---:|---:|---:|---:|---|---|",
    ]
    for r in rows:
        link = r["uplink"] if r["uplink"] == LOOPBACK else f"{r['uplink']} Mbit/s ({r['link']})"
        s = r["settings"]
        last = f"long side {s['long_side'] or 'full'}, q{s['jpeg_quality']}, {s['fps']:g} fps" if s else "-"
        lat = r["latency_ms"]
        out.append(
            f"| {link} | {' '.join(MODES[r['mode']])} | {r['results']} ({100 * r['answered']:.1f} %) "
            f"| {r['replay_s']} / {r['recorded_s']} s | {lat['p50']} / {lat['p95']} | {r['kb_per_frame']} | {last} "
            f"| {r['load_before'][0]:.2f} / {r['load_after'][0]:.2f} |"
        )
    return "\n".join(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=str(SHARED / "models/yolox_nano.onnx"))
    parser.add_argument("--video", default=str(SHARED / "media/pedestrians.avi"))
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--fps", type=float, default=10.0, help="the bag's recorded rate (default 10)")
    parser.add_argument("--size", default="1280x720")
    parser.add_argument("--transport", default="ws")
    parser.add_argument("--uplinks", default=f"{LOOPBACK},1.5", help="loopback and/or Mbit/s (default loopback,1.5)")
    parser.add_argument("--modes", default="auto,full", help=f"of {', '.join(MODES)} (default auto,full)")
    parser.add_argument("--link-mode", default="auto", choices=("auto", "netns", "userspace"))
    parser.add_argument("--quick", action="store_true", help="20 frames a row, no warm-up (a smoke test)")
    parser.add_argument("--out", default="results")
    args = parser.parse_args()
    if args.quick:
        args.frames = min(args.frames, 20)
    uplinks = [u for u in args.uplinks.split(",") if u]
    modes = [m for m in args.modes.split(",") if m]
    if not set(modes) <= set(MODES):
        raise SystemExit(f"unknown modes {modes}; known: {', '.join(MODES)}")
    for uplink in uplinks:
        if uplink != LOOPBACK:
            float(uplink)  # a rate in Mbit/s, or argparse's kind of error below
    out_dir = start_run("ros-replay", args.out, [args.model, args.video])
    if out_dir is None:
        return
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "camera"
        video_to_bag(args.video, bag, args.frames, args.fps, parse_size(args.size))
        if not args.quick:
            with netapp_process(args.model):
                pass  # the first start loads the model from disk into the page cache; the timed runs start warm
        with netapp_process(args.model) as (_, port):
            rows = [replay(bag, port, uplink, mode, args) for uplink in uplinks for mode in modes]
    head = f"{args.frames} frames at {args.size}, {args.fps:g} FPS, {args.transport}, link {args.link_mode}"
    report = f"{head}; {os.cpu_count()} CPUs\n\n{table(rows)}\n"
    (out_dir / "table.md").write_text(report)
    (out_dir / "summary.json").write_text(json.dumps({"size": args.size, "rows": rows}, indent=2))
    print(report)


if __name__ == "__main__":
    main()
