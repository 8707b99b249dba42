"""bench/robots.py's robot processes, each run as `python -m bench.robots --worker max|robots`: the in-process
maximum (the netapp's decode and detect, back to back), and robots streaming as NetAppClients or era-5g-clients,
with how they send (--clients), their priority classes (--priorities) and how they start (--start)."""

from __future__ import annotations

import argparse
import itertools
import json
import shlex
import sys
import threading
import time

from bench.netapps import CLIENT_TRANSPORTS, ENCODES_LIVE
from bench.robot import jpeg_frames

SOURCE_FPS = 25.0  # the rate the sample video is read at (which of its frames are taken), not the robots' pace


def worker_max(args) -> None:
    """The in-process maximum: decode and detect pre-encoded frames back to back for `duration` seconds."""
    from netapp.models import Detector
    from netapp.server.decoding.jpeg import decode_jpeg

    detector = Detector(model_config(args))
    detector.load()
    frames = jpeg_frames(args.video, SOURCE_FPS, args.size, 100)
    start = time.monotonic()
    done = detections = masks = 0
    while time.monotonic() - start < args.duration:
        found = detector.detect(decode_jpeg(frames[done % len(frames)]))
        detections += len(found)
        masks += sum(1 for d in found if d.get("mask"))
        done += 1
    elapsed = time.monotonic() - start
    print(json.dumps({"results_per_s": done / elapsed, "detections": detections / done, "masks": masks / done}))


def model_config(args):
    """The DetectorConfig `netapp serve --model MODEL MODEL_ARGS` makes (its --conf, --iou, --max-detections,
    --mask-format, --task, ...), for the in-process maximum: the same model, read and decoded the same way. Raises
    SystemExit (argparse's message) for flags that are not the netapp's model flags."""
    from netapp.models.options import add_model_arguments, detector_config

    parser = argparse.ArgumentParser(prog="--model-args", add_help=False)
    add_model_arguments(parser)
    parsed = parser.parse_args(shlex.split(args.model_args))
    parsed.threads = 0  # every core: the in-process maximum, as before
    return detector_config(parsed, args.model)


# How the robots' NetAppClients send, compared side by side with --clients.
CLIENTS = {
    "paced": {"pacing": True},  # the default: one frame at a time, held back, while the netapp is the bottleneck
    "unpaced": {"pacing": False},  # every frame due goes as soon as a slot is free (before pacing)
    "one-in-flight": {"pacing": False, "max_in_flight": 1},  # the next frame only once the last result is back
    # Socket.IO's long-polling start, then the upgrade (python-socketio's default, NetAppClient's before): behind
    # two replicas, half the robots' WebSockets are relayed by the replica they land on to their session's owner
    "polling-first": {"websocket_first": False},
}


def client_options(args) -> dict:
    return {"max_in_flight": args.max_in_flight} | CLIENTS[args.client]


# --priorities: the class token the bench's netapps take (`--priority-token high=SHA256`), so a robot may claim high
CLASS_TOKEN = "bench-high-class-token"
NO_PRIORITIES = "none"


def robot_class(assignment: str, i: int) -> str | None:
    """Robot i's class in an assignment such as 'high,low' (robot 0 high, the others low: the last repeats); None
    for 'none' (no robot claims a class: every one is normal, as before priorities)."""
    if assignment == NO_PRIORITIES:
        return None
    classes = assignment.split(",")
    return classes[min(i, len(classes) - 1)]


def raw_frames(video: str, size: tuple[int, int], count: int, fps: float = SOURCE_FPS) -> list:
    """BGR frames, for robots that encode on their own (H.264, the era-5g-client)."""
    from netapp.client.sources import open_source

    return list(itertools.islice(open_source(video, fps, size), count))


# How the robots start (--start): `connected` connects every robot, then all stream from one moment (the bench's
# way before issue 22); `storm` starts them at one moment, each streaming as soon as it is connected (a launch file
# starting a fleet: the connects, the INITs and the first frames all at once).
STARTS = ("connected", "storm")
ENCODING_ROBOTS = (*ENCODES_LIVE, "era5g")
TRANSPORTS = ("ws", "http", "frames", *ENCODING_ROBOTS)  # robots given BGR frames; the others send the pre-encoded JPEG


def unserved(exc: Exception) -> dict:
    """The summary of a robot that got no session: no results (its share 0), the error counted."""
    return {
        "frames_sent": 0,
        "results": 0,
        "results_per_s": 0.0,
        "duration_s": 1.0,
        "lost": 0,
        "errors": 1,
        "within_deadline": 0,
        "within_deadline_per_s": 0.0,
        "latencies_ms": [],
        "failed": repr(exc)[:300],
    }


READY = "ready"  # a robot process's line once its robots can start (with --start connected: once connected)


def worker_robots(args) -> None:
    """`--robots` robots in this process, each a NetAppClient (or an era-5g-client) on its own thread, streaming at
    `--fps` from the moment (wall clock) the orchestrator writes on stdin once every robot process is ready."""
    from bench.era5g_robot import Era5gRobot
    from netapp.apps.streaming import stream
    from netapp.client import NetAppClient

    raw = args.transport in ENCODING_ROBOTS
    frames = raw_frames(args.video, args.size, 50) if raw else jpeg_frames(args.video, SOURCE_FPS, args.size, 100)
    summaries: list[dict] = []
    lock = threading.Lock()
    connected = threading.Barrier(args.robots + 1, timeout=300)  # with --start connected: every robot connected
    go = threading.Event()
    start: dict[str, float] = {}

    def robot(i: int) -> None:
        priority = robot_class(args.priority, args.first + i)
        session = {"args": {"priority": priority}} if priority else {}
        if priority == "high":
            session["token"] = CLASS_TOKEN
        options = client_options(args) | session | {"deadline_ms": args.deadline_ms}
        offset = (i * 7) % len(frames)
        mine = itertools.cycle(frames[offset:] + frames[:offset])
        name = f"robot-{args.first + i}"
        era = args.transport == "era5g"
        arrivals: list[float] = []  # when each result came (wall clock), for the window every robot streamed in
        if era:
            client = Era5gRobot(args.url, name, arrivals)
        else:
            on_result = lambda _: arrivals.append(time.time())  # noqa: E731
            transport, codec = CLIENT_TRANSPORTS[args.transport]
            client = NetAppClient(args.url, transport, codec=codec, robot_id=name, on_result=on_result, **options)
        try:
            if args.start == "connected":
                try:
                    client.connect()
                finally:
                    connected.wait()  # connected or not: the others start all the same
            go.wait()
            time.sleep(max(0.0, start["at"] - time.time()))  # the common start, on the wall clock: pacing
            began = time.time()
            if args.start == "storm":
                client.connect()
            if era:
                summary = client.stream(mine, args.fps, args.duration)
            else:
                summary = stream(client, mine, args.fps, args.duration)
                summary["latencies_ms"] = list(client.stats.latencies_ms)
        except Exception as exc:  # not served (refused, or no session in time): counted as such, not left out
            go.wait()
            summary, began = unserved(exc), time.time()
        finally:
            client.close()
        summary["robot"] = args.first + i
        summary["arrivals"] = arrivals
        summary["started_s"] = began - start["at"]  # when it began to connect (storm) or stream, from the start
        summary["priority"] = priority or "normal"
        with lock:
            summaries.append(summary)

    threads = [threading.Thread(target=robot, args=(i,)) for i in range(args.robots)]
    for t in threads:
        t.start()
    if args.start == "connected":
        connected.wait()
    print(READY, flush=True)
    start["at"] = float(sys.stdin.readline())
    go.set()
    for t in threads:
        t.join()
    print(json.dumps(summaries))
