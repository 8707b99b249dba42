"""One robot for the benchmarks, run as its own process so its CPU and memory can be measured apart.

    python -m bench.robot --transport ws --url http://127.0.0.1:5896 --video V --fps 25 --duration 20 [--pre-encode]
    python -m bench.robot --transport ws --url EDGE --url CLOUD --policy hedge --deadline-ms 200 --video V ...
    python -m bench.robot --transport direct --model M --video V --fps 25 --duration 20

Prints one JSON line: the client summary plus the raw latencies and, per result, (latency, model time) in
`timed_ms`: the model's time is the processor's `process()` call (for a netapp, the Result's server-side
`inference_ms`), so the time spent outside the model can be told apart from the model's own swings. `direct`
decodes and detects the same JPEG frames in-process, paced the same way, newest frame wins: the pipeline without any
framework or network; it first runs `--warmup` frames untimed (onnxruntime's first few hundred runs are slower, and
the netapp has run them before it is measured).

A benchmark's `--variants` runs this from another checkout's root, so the robot and its client are that checkout's.
"""

from __future__ import annotations

import argparse
import itertools
import json
import resource
import time
from collections.abc import Callable

import numpy as np

from bench.netapps import CLIENT_TRANSPORTS, ENCODES_LIVE
from netapp.client.encoders import JpegEncoder
from netapp.client.send_settings import SendSettings
from netapp.client.sources import open_source
from netapp.client.stats import ClientStats

MAX_RAW = 300  # 640x480 BGR frames kept in memory (about 280 MB)
ROBOT_SETTINGS = SendSettings()  # what NetAppClient sends by default (made once: robot_jpeg is timed per frame)


def robot_jpeg(frame: np.ndarray) -> bytes:
    """`frame` as the JPEG NetAppClient sends by default: its own encoder, at its default settings."""
    return JpegEncoder().encode(0, frame, ROBOT_SETTINGS).payload


def jpeg_frames(video: str, fps: float, size: tuple[int, int], count: int) -> list[bytes]:
    """Encode up front, so the timed loop measures transport and server, not the robot's JPEG encoder."""
    return [robot_jpeg(f) for f in itertools.islice(open_source(video, fps, size), count)]


def paced_newest(frames: list[bytes], fps: float, answer: Callable[[bytes], tuple[list, float]]) -> dict:
    """`direct`'s loop: `frames` at `fps`, one at a time, newest frame wins; `answer(jpeg)` returns its detections and
    the model's time in ms. The summary with each result's (latency, model time) in `timed_ms`."""
    stats = ClientStats()
    model_ms: list[float] = []
    period = 1 / fps
    cpu0 = time.process_time()
    start = time.monotonic()
    index = 0
    while index < len(frames):
        due = start + index * period
        now = time.monotonic()
        if now < due:
            time.sleep(due - now)  # pacing the input rate
        latest = min(len(frames) - 1, int((time.monotonic() - start) / period))
        stats.add(offered=latest - index + 1, sent=1, dropped_client=latest - index, bytes_sent=len(frames[latest]))
        detections, model = answer(frames[latest])
        model_ms.append(model)
        stats.add_result((time.monotonic() - (start + latest * period)) * 1000, detections)
        index = latest + 1
    return stats.summary(max(time.monotonic() - start, len(frames) * period)) | {
        "latencies_ms": stats.latencies_ms,
        "timed_ms": list(zip(stats.latencies_ms, model_ms, strict=True)),
        "loop_cpu_s": time.process_time() - cpu0,
    }


def detector_answer(model: str, threads: int = 0) -> Callable[[bytes], tuple[list, float]]:
    """A loaded detector as `direct` runs it (and bench/floor.py's servers): a JPEG -> its detections and the model's
    time in ms, that time being the processor's `process()` call, as the netapp times it. `threads`: onnxruntime's
    intra-op threads, as `netapp serve --threads` (0: every core)."""
    from netapp.models import Detector, DetectorConfig
    from netapp.server.decoding.jpeg import decode_jpeg

    detector = Detector(DetectorConfig(model, threads=threads))
    detector.load()

    def answer(frame: bytes) -> tuple[list, float]:
        prepared = detector.prepare(decode_jpeg(frame), {})
        before = time.perf_counter_ns()
        detections = detector.process([prepared])[0]["detections"]
        return detections, (time.perf_counter_ns() - before) / 1e6

    return answer


def run_direct(args, size) -> dict:
    answer = detector_answer(args.model, args.model_threads)
    frames = jpeg_frames(args.video, args.fps, size, int(args.fps * args.duration))
    for i in range(args.warmup):
        answer(frames[i % len(frames)])
    return paced_newest(frames, args.fps, answer)  # newest wins, as in the netapp


def run_client(args, size) -> dict:
    from netapp.apps.streaming import stream
    from netapp.client import NetAppClient

    count = int(args.fps * args.duration) + 1
    if args.pre_encode and args.transport not in ENCODES_LIVE:
        # Up to MAX_RAW frames, then cycled: encoding a minute of video up front would take longer than the run.
        encoded = jpeg_frames(args.video, args.fps, size, min(count, MAX_RAW))
        frames = itertools.islice(itertools.cycle(encoded), count)
    else:
        # Decoded and resized up front (up to MAX_RAW frames, then cycled), so the robot's CPU is its encoder and
        # transport: reading the 50 FPS source would otherwise dominate it and hide the transports' difference.
        raw = list(itertools.islice(open_source(args.video, args.fps, size), min(count, MAX_RAW)))
        frames = itertools.islice(itertools.cycle(raw), count)
    fallback = None
    if args.fallback_model:
        from netapp.models import Detector, DetectorConfig

        fallback = Detector(DetectorConfig(args.fallback_model, threads=1))
    records: list[tuple[float, float, str, bool]] = []  # arrival (s since start), latency ms, source, late
    timed: list[tuple[float, float | None]] = []  # latency ms, the netapp's inference ms (None: no stamps)
    switches: list[tuple[float, str, str]] = []  # when, state, why
    start = time.monotonic()
    transport, codec = CLIENT_TRANSPORTS[args.transport]
    client = NetAppClient(
        args.url,
        transport=transport,
        codec=codec,
        max_in_flight=args.max_in_flight,
        policy=args.policy,
        deadline_ms=args.deadline_ms,
        fallback=fallback,
        on_result=lambda r: (
            records.append((time.monotonic() - start, r.latency_ms, r.source, r.late)),
            timed.append((r.latency_ms, r.breakdown.inference_ms if r.breakdown else None)),
        ),
        on_switch=lambda s: switches.append((time.monotonic() - start, s.state, s.reason)),
    )
    with client:
        cpu0 = time.process_time()
        start = time.monotonic()
        # A line before the summary: a benchmark that changes the link during the run starts its clock here.
        print(json.dumps({"streaming_at": start}), flush=True)
        summary = stream(client, frames, args.fps, args.duration, progress=None)
        return summary | {
            "latencies_ms": list(client.stats.latencies_ms),
            "timed_ms": timed,
            "loop_cpu_s": time.process_time() - cpu0,
            "start_monotonic": start,
            "records": records,
            "switch_log": switches,
        }


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--transport", required=True, choices=("direct", *CLIENT_TRANSPORTS))
    p.add_argument("--url", action="append", help="netapp URL (repeat for several, in order of preference)")
    p.add_argument("--policy", default="primary", help="with several URLs: primary, hedge or adaptive")
    p.add_argument("--deadline-ms", type=float, help="results older than this are late")
    p.add_argument("--fallback-model", help="ONNX model run on the robot while no netapp meets the deadline")
    p.add_argument("--model")
    p.add_argument("--video", required=True)
    p.add_argument("--fps", type=float, required=True)
    p.add_argument("--duration", type=float, required=True)
    p.add_argument("--size", default="640x480")
    p.add_argument("--max-in-flight", type=int, default=2)
    p.add_argument("--pre-encode", action="store_true", help="JPEG-encode frames before the timed loop")
    p.add_argument("--warmup", type=int, default=300, help="direct: frames detected untimed before the run")
    p.add_argument("--model-threads", type=int, default=0, help="direct: onnxruntime's threads (0: every core)")
    args = p.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    summary = run_direct(args, size) if args.transport == "direct" else run_client(args, size)
    # The process's own account: CPU from start to here (for `direct` this includes loading the model).
    summary["cpu_s"] = time.process_time()
    summary["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
