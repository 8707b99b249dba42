"""What the live ROS 2 bridge costs: per-frame latency from an image published on a ROS 2 topic over DDS to its
`Detection2DArray` received, against `netapp stream`'s path on the same frames (same netapp, same transport); issue
23's goal: the bridge adds <= 2 ms per frame.

    python -m bench.ros_bridge                                  # 640x480 and 1280x720, CompressedImage and Image
    python -m bench.ros_bridge --sizes 1280x720 --kinds raw --frames 100
    python -m bench.ros_bridge --quick                          # a few frames a case (the smoke test)

One `netapp serve` (the shared YOLOX-Nano) for every case. Per size and kind (`compressed`: JPEG `CompressedImage`,
`raw`: bgr8 `Image`), the same `--frames` frames of the video at `--fps`:

* `stream`: in this process, each message goes as `netapp stream` sends a recorded one (`to_frame`, then
  `NetAppClient.send` with the frame fitted to the model's input); latency from just before `to_frame` to the
  client's result callback.
* `bridge`: this process publishes each message on `/bench/image` over DDS (sensor-data QoS) with its header stamp
  the publish time, `netapp ros2` runs as its own process, and this process takes each `Detection2DArray` from
  `/bench/detections`; latency from the stamp to the array taken (one clock: one machine).

Both with `--adapt off` (the same frame size throughout, so the two paths do the same work). Also the DDS decode of
one message, with the bytes reading of `netapp/ros/dds_types.py` and as cyclonedds reads it without (a list of ints).
The bridge's count of images received includes the warm-up's (until its first answer); "its client's p50" is the
bridge's own `NetAppClient` latency (send to result, warm-up included): the bridge's p50 less it is the DDS legs.
Prints a table (also results/ros-bridge-<time>/table.md and runs.json) with the load average before and after.
"""

from __future__ import annotations

import argparse
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
from typing import Any

from bench.netapps import netapp_process, start_run
from bench.robot import robot_jpeg
from netapp.apps.streaming import parse_size
from netapp.client import NetAppClient
from netapp.client.sources import open_source

SHARED = Path("../shared")
TOPIC = "/bench/image"
DETECTIONS = "/bench/detections"  # not the default: a bridge under test elsewhere on the machine is not ours
KINDS = {"compressed": "sensor_msgs/msg/CompressedImage", "raw": "sensor_msgs/msg/Image"}
WARMUP_S = 30.0  # the bridge's start and DDS discovery, at most


def messages(args: argparse.Namespace, size: tuple[int, int], kind: str) -> list[Any]:
    """The frames as the camera publishes them (stamps set when each goes)."""
    from netapp.ros.dds_types import CompressedImage_, Header_, Image_

    out = []
    for frame in itertools.islice(open_source(args.video, args.fps, size), args.frames):
        if kind == "compressed":
            jpeg = robot_jpeg(frame)
            out.append(CompressedImage_(Header_(frame_id="camera"), "jpeg", jpeg))
        else:
            height, width = frame.shape[:2]
            out.append(Image_(Header_(frame_id="camera"), height, width, "bgr8", 0, width * 3, frame.tobytes()))
    return out


def stamp(message: Any) -> int:
    """Stamp `message` with the time now (ns since the epoch); that time."""
    from netapp.ros.dds_types import Time_

    now = time.time_ns()
    message.header.stamp = Time_(now // 10**9, now % 10**9)
    return now


def default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def paced(items: list[Any], fps: float) -> Any:
    start = time.monotonic()
    for i, item in enumerate(items):
        delay = start + i / fps - time.monotonic()
        if delay > 0:
            time.sleep(delay)  # the camera's frame rate
        yield item


def via_stream(url: str, args: argparse.Namespace, kind: str, msgs: list[Any]) -> list[float]:
    """`netapp stream`'s path in this process: latency (ms) of each answered frame."""
    from netapp.ros.images import to_frame

    sent: dict[int, int] = {}
    latencies: list[float] = []
    lock = threading.Lock()

    def on_result(result: Any) -> None:
        now = time.time_ns()
        with lock:
            began = sent.pop(result.timestamp, None)
            if began is not None:
                latencies.append((now - began) / 1e6)

    with NetAppClient(url, transport=args.transport, adapt="off") as client:
        client.on_result = on_result
        for message in paced(msgs, args.fps):
            began = stamp(message)
            frame = to_frame(KINDS[kind], message, None)
            timestamp = client.send(frame.wire(as_recorded=False))
            with lock:
                sent[timestamp] = began
        client.wait_idle(5.0)
    return latencies


def via_bridge(url: str, args: argparse.Namespace, kind: str, msgs: list[Any]) -> tuple[list[float], dict]:
    """Through `netapp ros2` over DDS: latency (ms) of each array taken, and the bridge's summary."""
    from cyclonedds.core import Listener, Policy, Qos
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from netapp.ros.bridge import DETECTIONS_DEPTH, SENSOR_DATA_DEPTH, dds_topic
    from netapp.ros.dds_types import Detection2DArray_

    arrived: dict[int, int] = {}
    first = threading.Event()

    def on_arrays(reader: Any) -> None:
        now = time.time_ns()
        for array in reader.take(N=DETECTIONS_DEPTH):
            arrived[array.header.stamp.sec * 10**9 + array.header.stamp.nanosec] = now
        first.set()

    participant = DomainParticipant(args.domain)
    sensor = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(SENSOR_DATA_DEPTH), Policy.Durability.Volatile)
    reliable = Qos(Policy.Reliability.Reliable(0), Policy.History.KeepLast(DETECTIONS_DEPTH))
    writer = DataWriter(participant, Topic(participant, dds_topic(TOPIC), type(msgs[0])), qos=sensor)
    reader = DataReader(
        participant,
        Topic(participant, dds_topic(DETECTIONS), Detection2DArray_),
        qos=reliable,
        listener=Listener(on_data_available=on_arrays),
    )
    command = [sys.executable, "-m", "netapp", "ros2", url, "--image-topic", TOPIC, "--transport", args.transport]
    command += ["--detections-topic", DETECTIONS, "--adapt", "off", "--domain", str(args.domain), "--json"]
    command += ["--compressed"] if kind == "compressed" else []
    # Ctrl-C's signal ends it with its summary; a bench started in the background would pass SIGINT on ignored.
    bridge = subprocess.Popen(command, stdout=subprocess.PIPE, text=True, preexec_fn=default_sigint)
    try:
        deadline = time.monotonic() + WARMUP_S
        for message in itertools.cycle(msgs[:10]):  # until the bridge answers: discovery, the netapp's session
            if first.is_set() or time.monotonic() > deadline or bridge.poll() is not None:
                break
            stamp(message)
            writer.write(message)
            first.wait(1 / args.fps)
        if not first.is_set():
            raise RuntimeError(f"the bridge answered nothing within {WARMUP_S:g} s")
        time.sleep(1.0)  # the warm-up's last arrays land before the timed frames go
        arrived.clear()
        published = []
        for message in paced(msgs, args.fps):
            published.append(stamp(message))
            writer.write(message)
        end = time.monotonic() + 5.0
        while time.monotonic() < end and not all(s in arrived for s in published[-3:]):
            time.sleep(0.05)  # the last arrays on their way (another process answers them)
    finally:
        bridge.send_signal(signal.SIGINT)  # as Ctrl-C: it prints its summary and exits
        try:
            out, _ = bridge.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            bridge.kill()
            out = bridge.communicate()[0]
        reader.set_listener(None)
    summary = json.loads(out.strip().splitlines()[-1]) if out.strip() else {}
    return [(arrived[s] - s) / 1e6 for s in published if s in arrived], summary


def decode_ms(message: Any) -> dict[str, float]:
    """The DDS decode of one message, ms: with the bytes reading, and as a generic reader sees it (plus bytes())."""
    from netapp.ros.dds_types import as_generic_reader_sees_it

    wire = message.serialize()
    generic = as_generic_reader_sees_it(type(message))

    def best(fn: Any) -> float:
        times = []
        for _ in range(3):
            began = time.perf_counter()
            fn()
            times.append(time.perf_counter() - began)
        return round(1000 * min(times), 2)

    return {
        "bytes": best(lambda: bytes(type(message).deserialize(wire).data)),
        "list": best(lambda: bytes(generic.deserialize(wire).data)),
    }


def case(url: str, args: argparse.Namespace, size_text: str, kind: str) -> dict[str, Any]:
    msgs = messages(args, parse_size(size_text), kind)
    load_before = os.getloadavg()
    stream_ms = via_stream(url, args, kind, msgs)
    bridge_ms, summary = via_bridge(url, args, kind, msgs)
    med_s = statistics.median(stream_ms) if stream_ms else None
    med_b = statistics.median(bridge_ms) if bridge_ms else None
    return {
        "size": size_text,
        "kind": kind,
        "frames": len(msgs),
        "kb_per_image": round(sum(len(m.data) for m in msgs) / len(msgs) / 1000, 1),
        "stream_answered": len(stream_ms),
        "bridge_answered": len(bridge_ms),
        "stream_p50": None if med_s is None else round(med_s, 1),
        "bridge_p50": None if med_b is None else round(med_b, 1),
        "added_ms": None if med_s is None or med_b is None else round(med_b - med_s, 1),
        "decode_ms": decode_ms(msgs[0]),
        "bridge_summary": summary,
        "load_before": round(load_before[0], 2),
        "load_after": round(os.getloadavg()[0], 2),
    }


def table(rows: list[dict[str, Any]]) -> str:
    out = [
        "| image | KB a message | answered stream / bridge (images the bridge got) | `netapp stream` p50 ms | "
        "bridge p50 ms | added ms | its client's p50 ms | DDS decode ms: bytes / list of ints | load before / after |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        name = "CompressedImage (JPEG)" if r["kind"] == "compressed" else "Image (bgr8)"
        got = r["bridge_summary"].get("received", "-")
        own = (r["bridge_summary"].get("latency_ms") or {}).get("p50", "-")
        out.append(
            f"| {name} {r['size']} | {r['kb_per_image']} | {r['stream_answered']} / {r['bridge_answered']} of "
            f"{r['frames']} ({got}) | {r['stream_p50']} | {r['bridge_p50']} | {r['added_ms']} | {own} "
            f"| {r['decode_ms']['bytes']} / {r['decode_ms']['list']} | {r['load_before']:.2f} / {r['load_after']:.2f} |"
        )
    return "\n".join(out)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=str(SHARED / "models/yolox_nano.onnx"))
    parser.add_argument("--video", default=str(SHARED / "media/pedestrians.avi"))
    parser.add_argument("--frames", type=int, default=200, help="frames a case (default 200)")
    parser.add_argument("--fps", type=float, default=10.0, help="the camera's rate (default 10)")
    parser.add_argument("--sizes", default="640x480,1280x720")
    parser.add_argument("--kinds", default="compressed,raw", help="of compressed, raw")
    parser.add_argument("--transport", default="ws")
    parser.add_argument("--domain", type=int, default=23, help="the DDS domain (default 23: not the tests' 0)")
    parser.add_argument("--quick", action="store_true", help="10 frames a case (a smoke test, not a measurement)")
    parser.add_argument("--out", default="results")
    args = parser.parse_args()
    if args.quick:
        args.frames = min(args.frames, 10)
    kinds = [k for k in args.kinds.split(",") if k]
    if not set(kinds) <= set(KINDS):
        raise SystemExit(f"unknown kinds {kinds}; known: {', '.join(KINDS)}")
    out_dir = start_run("ros-bridge", args.out, [args.model, args.video])
    if out_dir is None:
        return 2
    with netapp_process(args.model) as (_, port):
        url = f"http://127.0.0.1:{port}"
        rows = [case(url, args, size, kind) for size in args.sizes.split(",") if size for kind in kinds]
    report = (
        f"{args.frames} frames a case at {args.fps:g} FPS, {args.transport}; {os.cpu_count()} CPUs\n\n{table(rows)}\n"
    )
    (out_dir / "table.md").write_text(report)
    (out_dir / "runs.json").write_text(json.dumps(rows, indent=2))
    print(report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
