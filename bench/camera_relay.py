"""What a relayed WATCH costs (docs/cameras.md#several-replicas): one camera, two netapp replicas sharing its Lease on
the Kubernetes API emulator, one watcher at the replica that pulls it and one at the other, which relays it. For each:
results per second, results missing against the direct watcher, and the delivery delay (when the watcher got the
result, less the holder's own `send_timestamp`: both monotonic clocks of this one machine).

Real parts: GStreamer's RTSP server from Debian as the camera, two `netapp serve` processes with the shared
YOLOX-Nano, kmock as the API server, `netapp watch`'s subscriber. Prints a table with the load average.

    flock /tmp/heavy.lock .venv/bin/python -m bench.camera_relay [--duration 20] [--fps 15]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path

from bench.cameras import MODEL, load, metric
from netapp.serve_process import NetAppProcess, free_port
from tests.support.api_emulator import ApiEmulator
from tests.support.kube_emulator import kubeconfig
from tests.support.rtsp_camera import RtspCamera, gstreamer_problem
from tests.support.watcher import Watcher


def wait(check, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not check():
        if time.monotonic() > deadline:
            raise SystemExit(f"timed out waiting for {what}")
        time.sleep(0.1)


def watch(stack: ExitStack, url: str) -> Watcher:
    """A watcher of the camera at `url` that got results (a replica answers `elsewhere` until its first Lease round)."""
    for _ in range(30):
        watcher = Watcher(url, "door").__enter__()
        wait(lambda w=watcher: w.count() > 3 or w.error is not None, 60, f"results at {url}")
        if watcher.error is None:
            stack.callback(watcher.__exit__)
            return watcher
        watcher.__exit__()
        time.sleep(1)
    raise SystemExit(f"{url} never took the WATCH")


def row(name: str, got: list, seconds: float, direct: set[int]) -> str:
    delays = sorted(at * 1e3 - r["send_timestamp"] / 1e6 for at, r in got if isinstance(r.get("send_timestamp"), int))
    stamps = {r["timestamp"] for _, r in got}
    missing = len(direct - stamps)
    p50 = statistics.median(delays) if delays else float("nan")
    p99 = delays[min(len(delays) - 1, int(len(delays) * 0.99))] if delays else float("nan")
    return f"| {name} | {len(got) / seconds:.1f} | {missing} | {p50:.2f} | {p99:.2f} |"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=20.0, help="seconds measured (default %(default)s)")
    parser.add_argument("--fps", type=int, default=15, help="the camera's rate (default %(default)s)")
    args = parser.parse_args()
    problem = gstreamer_problem()
    if problem:
        raise SystemExit(problem)
    with ExitStack() as stack, tempfile.TemporaryDirectory() as scratch:
        camera = RtspCamera(free_port(), 640, 480, args.fps).start()
        stack.callback(camera.stop)
        api = stack.enter_context(ApiEmulator())
        config = Path(scratch) / "kubeconfig"
        config.write_text(kubeconfig(api.url))
        os.environ.update(KUBECONFIG=str(config), NETAPP_NAME="bench")
        os.environ.pop("KUBERNETES_SERVICE_HOST", None)
        flags = ("--model", str(MODEL), "--source", f"door={camera.url}", "--camera-leases", "robots")
        holder = stack.enter_context(NetAppProcess(*flags, advertise=True))
        wait(lambda: metric(holder.url, 'netapp_source_up{source="door"}') == 1, 60, "the holder to pull")
        other = stack.enter_context(NetAppProcess(*flags, advertise=True))
        direct, relayed = watch(stack, holder.url), watch(stack, other.url)
        start = time.monotonic()
        time.sleep(args.duration)  # the measurement itself: both watchers collect meanwhile
        end = time.monotonic()
        a = [(at, r) for at, r in direct.since(start) if at < end]
        b = [(at, r) for at, r in relayed.since(start) if at < end]
        # a result sent just before the window's end may reach the relayed watcher after it: compare by the direct's
        stamps = {r["timestamp"] for at, r in a if at < end - 1}
        seconds = end - start
        print(f"camera 640x480 at {args.fps} fps, {seconds:.0f} s, YOLOX-Nano, 2 replicas; {load()}")
        print("| watcher | results/s | missing | delivery p50 ms | delivery p99 ms |")
        print("|---|---|---|---|---|")
        print(row("at the holder (direct)", a, seconds, stamps))
        print(row("at the other replica (relayed)", b, seconds, stamps))
        decoded = metric(other.url, 'netapp_source_pictures_decoded_total{source="door"}')
        print(f"pictures decoded by the other replica: {decoded:.0f} (the camera is pulled once)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
