"""Cameras the netapp pulls (RTSP): can one core decode a 1080p camera at 30 fps, how fairly one netapp serves 4
cameras, and how soon results come back after a camera was away for 10 s.

Real parts: GStreamer's RTSP server from Debian as each camera (`tests/support/rtsp_camera.py`, its own process),
`netapp serve --source ...` as its own process with the shared YOLOX-Nano, results read by `netapp watch`'s
subscriber. Prints one table per part, with the load average. Run under `flock /tmp/heavy.lock`.

    flock /tmp/heavy.lock .venv/bin/python -m bench.cameras [--parts decode,four,outage] [--duration 20]
"""

from __future__ import annotations

import argparse
import os
import re
import time
from contextlib import ExitStack

import requests

from netapp.serve_process import NetAppProcess, free_port
from tests.support.paths import SHARED
from tests.support.rtsp_camera import RtspCamera, gstreamer_problem
from tests.support.watcher import Watcher

MODEL = SHARED / "models" / "yolox_nano.onnx"
FULL_HD = (1920, 1080)


def load() -> str:
    return "load average " + ", ".join(f"{x:.2f}" for x in os.getloadavg())


def metric(url: str, sample: str) -> float:
    text = requests.get(url + "/metrics", timeout=5).text
    return sum(float(line.rsplit(" ", 1)[1]) for line in text.splitlines() if line.startswith(sample))


def decode_part(seconds: float) -> list[str]:
    """1080p at 30 fps (the shared pedestrian video, scaled up), x264 zero-latency as a camera sends it: decoded by
    one thread and by FFmpeg's default slice threads (the netapp's reader), and a live 1080p30 camera pulled by a
    netapp."""
    import av
    import cv2

    frames = 90
    encoder = av.CodecContext.create("libx264", "w")
    encoder.width, encoder.height, encoder.pix_fmt = *FULL_HD, "yuv420p"
    encoder.framerate = 30
    encoder.options = {"preset": "ultrafast", "tune": "zerolatency", "g": "30"}
    video = cv2.VideoCapture(str(SHARED / "media" / "pedestrians.avi"))  # real content: moving people, a street
    packets = []
    for _ in range(frames):
        ok, image = video.read()
        if not ok:
            break
        image = cv2.resize(image, FULL_HD, interpolation=cv2.INTER_LINEAR)
        picture = av.VideoFrame.from_ndarray(image, format="bgr24").reformat(format="yuv420p")
        packets += [bytes(p) for p in encoder.encode(picture)]
    packets += [bytes(p) for p in encoder.encode(None)]
    rows = ["| decoder | ms per 1080p picture | CPU ms per picture | pictures/s | keeps up with 30 fps |"]
    rows.append("|---|---|---|---|---|")
    for threads, name in ((1, "one thread"), (0, "FFmpeg default (slice threads)")):
        ctx = av.CodecContext.create("h264", "r")
        ctx.thread_count = threads
        start, cpu = time.perf_counter(), time.process_time()
        decoded = sum(len(ctx.decode(av.Packet(p))) for p in packets)
        wall, cpu = time.perf_counter() - start, time.process_time() - cpu
        keeps_up = "yes" if decoded / wall >= 30 else "no"
        rows.append(
            f"| {name} | {1000 * wall / decoded:.1f} | {1000 * cpu / decoded:.1f} | {decoded / wall:.0f} | {keeps_up} |"
        )
    rows.append("")
    rows.append(live_1080(seconds))
    return rows


def live_1080(seconds: float) -> str:
    with ExitStack() as stack:
        camera = stack.enter_context(RtspCamera(free_port(), *FULL_HD, fps=30))
        netapp = stack.enter_context(NetAppProcess("--model", str(MODEL), "--source", f"hd={camera.url}"))
        watcher = stack.enter_context(Watcher(netapp.url, "hd"))
        deadline = time.monotonic() + 60
        while not watcher.count() and time.monotonic() < deadline:
            time.sleep(0.1)  # polling for the first result, with a deadline
        decoded0, start = metric(netapp.url, 'netapp_source_pictures_decoded_total{source="hd"}'), time.monotonic()
        got0 = watcher.count()
        time.sleep(seconds)  # the measured interval
        elapsed = time.monotonic() - start
        decoded = metric(netapp.url, 'netapp_source_pictures_decoded_total{source="hd"}') - decoded0
        keyframes_only = metric(netapp.url, 'netapp_source_keyframes_only{source="hd"}')
        corrupt = metric(netapp.url, 'netapp_source_pictures_skipped_total{reason="corrupt",source="hd"}')
        return (
            f"live 1080p30 camera pulled by a netapp for {elapsed:.0f} s: {decoded / elapsed:.1f} pictures decoded/s, "
            f"{(watcher.count() - got0) / elapsed:.1f} results/s, keyframes only: {'yes' if keyframes_only else 'no'}, "
            f"corrupt pictures skipped: {corrupt:.0f}"
        )


def four_part(seconds: float, size: tuple[int, int], fps: int) -> list[str]:
    names = [f"cam{i}" for i in range(4)]
    with ExitStack() as stack:
        cams = [stack.enter_context(RtspCamera(free_port(), *size, fps=fps)) for _ in names]
        sources = [a for name, cam in zip(names, cams, strict=True) for a in ("--source", f"{name}={cam.url}")]
        netapp = stack.enter_context(NetAppProcess("--model", str(MODEL), *sources))
        watchers = [stack.enter_context(Watcher(netapp.url, name)) for name in names]
        deadline = time.monotonic() + 60
        while not all(w.count() for w in watchers) and time.monotonic() < deadline:
            time.sleep(0.1)  # polling for every camera's first result, with a deadline
        start = time.monotonic()
        time.sleep(seconds)  # the measured interval
        end = time.monotonic()
        rates = [len([at for at, _ in w.since(start) if at <= end]) / (end - start) for w in watchers]
        wall_offset_ns = time.time_ns() - time.monotonic_ns()  # the subscriber shares the netapp's clock (one host)
        latencies = sorted(
            (at * 1e9 + wall_offset_ns - r["timestamp"]) / 1e6
            for w in watchers
            for at, r in w.since(start)
            if at <= end
        )
    rows = [
        f"4 cameras, {size[0]}x{size[1]} at {fps} fps each, one netapp (YOLOX-Nano), {seconds:.0f} s:",
        "",
        "| camera | results/s | share of the mean |",
        "|---|---|---|",
    ]
    mean = sum(rates) / len(rates)
    rows += [f"| {n} | {r:.1f} | {r / mean:.2f} |" for n, r in zip(names, rates, strict=True)]
    p50, p95 = latencies[len(latencies) // 2], latencies[int(len(latencies) * 0.95)]
    rows += [
        "",
        f"total {sum(rates):.1f} results/s; fair share (min/max) {min(rates) / max(rates):.2f}; picture decoded to "
        f"result at the subscriber p50 {p50:.0f} ms, p95 {p95:.0f} ms",
    ]
    return rows


def outage_part(repeats: int, away_s: float) -> list[str]:
    rows = ["| try | camera away (s) | results again after it is back (s) |", "|---|---|---|"]
    with ExitStack() as stack:
        camera = stack.enter_context(RtspCamera(free_port(), 640, 480, fps=15))
        netapp = stack.enter_context(NetAppProcess("--model", str(MODEL), "--source", f"door={camera.url}"))
        watcher = stack.enter_context(Watcher(netapp.url, "door"))
        for n in range(repeats):
            deadline = time.monotonic() + 60
            while not watcher.since(time.monotonic() - 0.5) and time.monotonic() < deadline:
                time.sleep(0.05)  # polling for results flowing, with a deadline
            camera.stop()
            away = time.monotonic()
            time.sleep(away_s)  # the outage itself
            camera.start()
            back = time.monotonic()
            deadline = back + 30
            while not watcher.since(back) and time.monotonic() < deadline:
                time.sleep(0.02)  # polling for the first result after the camera is back, with a deadline
            got = watcher.since(back)
            resumed = f"{got[0][0] - back:.2f}" if got else "none within 30 s"
            rows.append(f"| {n + 1} | {back - away:.1f} | {resumed} |")
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--parts", default="decode,four,outage")
    parser.add_argument("--duration", type=float, default=20.0, help="seconds measured per part (default 20)")
    parser.add_argument("--size", default="640x480", help="the 4 cameras' size (default 640x480)")
    parser.add_argument("--fps", type=int, default=15, help="the 4 cameras' frame rate (default 15)")
    parser.add_argument("--repeats", type=int, default=3, help="outages (default 3)")
    args = parser.parse_args()
    problem = gstreamer_problem()
    if problem or not MODEL.exists():
        print(problem or f"the shared model is absent: {MODEL}")
        return 2
    size = tuple(int(v) for v in re.split("x", args.size))
    for part in args.parts.split(","):
        before = load()
        if part == "decode":
            rows = decode_part(args.duration / 2)
        elif part == "four":
            rows = four_part(args.duration, size, args.fps)
        elif part == "outage":
            rows = outage_part(args.repeats, 10.0)
        else:
            parser.error(f"unknown part {part!r}: decode, four or outage")
        print(f"\n## {part} ({before} before, {load()} after)\n")
        print("\n".join(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
