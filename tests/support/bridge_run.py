"""One run of the live ROS 2 bridge for its tests: `netapp ros2` in a process of its own, a camera process
publishing grey 160x160 images (tests/support/dds_publisher.py), and what a subscriber in the test's process takes."""

from __future__ import annotations

import signal
import subprocess
import sys
from typing import Any

from tests.support.paths import ROOT


def run_bridge(url: str, reader: Any, image_topic: str, want: int, frames: int, *args: str) -> tuple[list, str, int]:
    """Bridge `image_topic` to the netapp at `url` (with `args`) while the camera publishes `frames` images; take
    `want` samples from `reader` (each within 8 s), then stop the bridge as a container is stopped (SIGTERM, so it
    ends with its summary). The samples, the bridge's stdout and its exit code."""
    from cyclonedds.util import duration

    bridge = subprocess.Popen(
        [sys.executable, "-m", "netapp", "ros2", url, "--image-topic", image_topic, "--duration", "60", *args],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        text=True,
    )
    camera = subprocess.Popen([sys.executable, "-m", "tests.support.dds_publisher", image_topic, str(frames)], cwd=ROOT)
    samples = []
    try:
        for sample in reader.take_iter(timeout=duration(seconds=8)):  # blocks until each arrives, 8 s at most
            samples.append(sample)
            if len(samples) >= want:
                break
    finally:
        camera.wait(timeout=30)
        bridge.send_signal(signal.SIGTERM)
        out, _ = bridge.communicate(timeout=30)
    return samples, out, bridge.returncode
