"""What each picture step costs a frame, as a robot sends it: the robot's shrink and encoders, the netapp's decoders
and letterbox, back to back and paced as a robot at 25 FPS paces them (caches and threads go cold between frames).

    python -m bench.picture_costs                       # 640x480 frames of pedestrians.avi, YOLOX-Nano's 416x416 input
    python -m bench.picture_costs --frames 300 --pace-ms 40 --size 1280x720

Every step runs in one thread with OpenCV on one thread (as `netapp serve` runs it). The send size is what
`NetAppClient` sends for the model's input (`netapp.client.sizing.send_size`); `direct` and the benchmarks'
pre-encoded JPEG frames are decoded at the camera's size. Prints a table of medians (µs) and writes it to
results/picture-costs-<time>/table.md.
"""

from __future__ import annotations

import argparse
import itertools
import os
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from bench.netapps import start_run
from bench.robot import robot_jpeg

ROOT = Path(__file__).resolve().parent.parent


def steps(frames: list[np.ndarray], input_size: tuple[int, int]) -> dict[str, Callable[[int], object]]:
    """Each step as a function of a frame's index, its inputs made up front so that only the step is timed."""
    from netapp.client.h264 import H264Encoder
    from netapp.client.sender import shrink
    from netapp.client.sizing import send_size
    from netapp.models.preprocess import letterbox
    from netapp.server.decoding.h264 import StreamDecoder
    from netapp.server.decoding.jpeg import decode_jpeg

    height, width = frames[0].shape[:2]
    sent = send_size((width, height), input_size)
    small = [shrink(f, sent) for f in frames]

    def fitted(image: np.ndarray) -> object:  # YOLOX's letterbox, as the netapp's detector makes it
        return letterbox(image, (input_size[1], input_size[0]), center=False, rgb=False, scale=1.0)

    full_jpegs, small_jpegs = [robot_jpeg(f) for f in frames], [robot_jpeg(f) for f in small]
    encoder = H264Encoder(*sent)
    packets = [encoder.encode(f)[0] for f in small]  # one stream, its first packet a keyframe
    decoder = StreamDecoder()

    def h264_encode(i: int) -> object:
        nonlocal encoder
        if i == 0:  # a run starts a new stream: its first frame is a keyframe, as the packets were made
            encoder = H264Encoder(*sent)
        return encoder.encode(small[i])

    def h264_decode(i: int) -> object:
        if i == 0:
            decoder.reset()
        return fitted(decoder.decode(packets[i], *sent))

    return {
        f"robot: shrink {width}x{height} -> {sent[0]}x{sent[1]}": lambda i: shrink(frames[i], sent),
        f"robot: JPEG encode {sent[0]}x{sent[1]}": lambda i: robot_jpeg(small[i]),
        f"robot: H.264 encode {sent[0]}x{sent[1]} (libx264 ultrafast, zerolatency)": h264_encode,
        f"netapp: JPEG decode + letterbox {sent[0]}x{sent[1]}": lambda i: fitted(decode_jpeg(small_jpegs[i])),
        f"netapp: H.264 decode + letterbox {sent[0]}x{sent[1]} (PyAV)": h264_decode,
        f"direct, or a frame sent at the camera's size: JPEG decode + letterbox {width}x{height}": lambda i: fitted(
            decode_jpeg(full_jpegs[i])
        ),
    }


def median_us(step: Callable[[int], object], count: int, pace_s: float) -> float:
    """The median time of `step` over frames 0..count-1 (the first tenth left out: a stream's start), each call
    `pace_s` after the last one ended."""
    times = []
    for i in range(count):
        if pace_s:
            time.sleep(pace_s)
        start = time.perf_counter_ns()
        step(i)
        times.append((time.perf_counter_ns() - start) / 1e3)
    return statistics.median(times[count // 10 :])


def main() -> int:
    from netapp.client.sources import open_source

    shared = ROOT.parent / "shared"
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--video", default=str(shared / "media" / "pedestrians.avi"))
    p.add_argument("--size", default="640x480", help="the camera's frame size")
    p.add_argument("--input-size", default="416x416", help="the model's input, WIDTHxHEIGHT (YOLOX-Nano's)")
    p.add_argument("--frames", type=int, default=200, help="frames per step and mode")
    p.add_argument("--pace-ms", type=float, default=40.0, help="the paced mode's gap between frames (25 FPS)")
    p.add_argument("--repeat", type=int, default=2, help="passes over every step, interleaved; medians shown")
    p.add_argument("--out", default=str(ROOT / "results"))
    p.add_argument("--quick", action="store_true", help="12 frames a step, 1 ms apart, one pass (the tests)")
    args = p.parse_args()
    if args.quick:
        args.frames, args.pace_ms, args.repeat = 12, 1.0, 1
    out_dir = start_run("picture-costs", args.out, (args.video,))
    if out_dir is None:
        return 2
    cv2.setNumThreads(1)
    size = tuple(int(v) for v in args.size.split("x"))
    input_size = tuple(int(v) for v in args.input_size.split("x"))
    frames = list(itertools.islice(open_source(args.video, 25, size), args.frames))
    timed = steps(frames, input_size)  # type: ignore[arg-type]
    runs: dict[tuple[str, float], list[float]] = {}
    for _ in range(args.repeat):
        for name, step in timed.items():
            for pace_s in (0.0, args.pace_ms / 1e3):
                runs.setdefault((name, pace_s), []).append(median_us(step, len(frames), pace_s))
    lines = [f"| step | back to back µs | paced ({args.pace_ms:g} ms apart) µs |", "|---|---:|---:|"]
    for name in timed:
        back, paced = (statistics.median(runs[(name, pace)]) for pace in (0.0, args.pace_ms / 1e3))
        lines.append(f"| {name} | {back:,.0f} | {paced:,.0f} |")
    report = "\n".join(lines) + f"\n\nload average at the end: {os.getloadavg()[0]:.2f}\n"
    (out_dir / "table.md").write_text(report)
    print(report)
    print(f"written: {out_dir}/table.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
