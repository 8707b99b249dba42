"""A real robot (NetAppClient, the shared 1280x720 video at 10 fps) and a real netapp (YOLOX-Nano) through the link
emulator (userspace, the 5G profile's delay and jitter): when the uplink steps down, a robot whose uplink adapts
keeps getting results while its bytes per frame fall; one that does not adapt sends as before."""

from __future__ import annotations

import dataclasses
import statistics
import threading
import time
from collections.abc import Iterator

import pytest

from bench.linkemu import PROFILES, Change, LinkEmulator, LinkSchedule
from netapp.client import NetAppClient
from netapp.client.delivery import Result
from netapp.client.sources import open_source
from netapp.models import Detector, DetectorConfig
from tests.support.polling import wait_until

FAST, THIN = 20.0, 0.5  # Mbit/s up, before and after the step


@pytest.fixture
def netapp_url(serve, real_model_path) -> str:
    return serve(Detector(DetectorConfig(str(real_model_path)))).url


@pytest.fixture
def stepping_link(netapp_url: str) -> Iterator[tuple[LinkEmulator, str]]:
    """A 5G link (no loss) whose uplink steps from FAST to THIN when the test starts its schedule."""
    port = int(netapp_url.rsplit(":", 1)[1])
    profile = dataclasses.replace(PROFILES["5g"], loss_pct=0.0, rate_mbit_up=FAST)
    schedule = LinkSchedule(changes=(Change(0, up_mbit=THIN),))
    emu = LinkEmulator(profile, ("127.0.0.1", port), mode="userspace", seed=1, schedule=schedule, hold_schedule=True)
    with emu as (host, link_port):
        yield emu, f"http://{host}:{link_port}"


class Camera:
    """The video at 10 fps from a thread into a client, until stopped; results kept as they come."""

    def __init__(self, client: NetAppClient, video: str) -> None:
        self.client = client
        self.results: list[Result] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._frames = open_source(video, 10)
        client.on_result = self._keep
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _keep(self, result: Result) -> None:
        with self._lock:
            self.results.append(result)

    def _run(self) -> None:
        for frame in self._frames:
            if self._stop.is_set():
                return
            self.client.send(frame)
            self._stop.wait(0.1)  # the camera's frame rate

    def since(self, timestamp_ns: int) -> list[Result]:
        """Results of frames sent after `timestamp_ns` (a result's timestamp is its frame's send time)."""
        with self._lock:
            return [r for r in self.results if r.timestamp > timestamp_ns]

    def __enter__(self) -> Camera:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


def frame_bytes(results: list[Result]) -> float:
    return statistics.median(r.sent["bytes"] for r in results if r.sent)


def test_a_robot_whose_uplink_steps_down_keeps_getting_results_with_fewer_bytes(stepping_link, media_dir):
    emu, url = stepping_link
    with NetAppClient(url, adapt="auto") as client, Camera(client, str(media_dir / "pedestrians.avi")) as camera:
        wait_until(lambda: len(camera.since(0)) >= 5, 20, "the first results")
        first = frame_bytes(camera.since(0)[:5])

        def climbed() -> float | None:  # the fast link carries frames at least twice the first ones' bytes
            latest = frame_bytes(camera.since(0)[-5:])
            return latest if latest >= 2 * first else None

        before = wait_until(climbed, 40, "steps up on the fast link")
        step = time.time_ns()
        emu.start_schedule()  # the uplink: FAST -> THIN Mbit/s

        def smaller() -> list[Result] | None:
            late = camera.since(step)[-3:]
            return late if len(late) == 3 and frame_bytes(late) < 0.6 * before else None

        thin = wait_until(smaller, 40, "smaller frames arriving over the thin uplink")
        report = client.adapt_report()
    assert all(r.detections for r in thin)  # still people found in each
    assert report["change_count"] >= 2 and any(c["reason"] != "probe up" for c in report["changes"])


def test_a_robot_that_does_not_adapt_sends_as_before(stepping_link, media_dir):
    emu, url = stepping_link
    with NetAppClient(url) as client, Camera(client, str(media_dir / "pedestrians.avi")) as camera:
        start = time.time_ns()
        wait_until(lambda: len(camera.since(start)) >= 5, 20, "results on the fast link")
        sent_before = client.stats.bytes_sent / client.stats.sent
        step = time.time_ns()
        emu.start_schedule()
        wait_until(lambda: len(camera.since(step)) >= 3, 40, "results over the thin uplink")
        assert client.adapt_report() is None
        sent_after = client.stats.bytes_sent / client.stats.sent
    assert all(r.sent is None for r in camera.results)
    assert abs(sent_after - sent_before) < 0.1 * sent_before  # the same quality whatever the link


def test_an_h264_robot_gets_a_bitrate_and_its_results(stepping_link, media_dir):
    pytest.importorskip("av")
    _, url = stepping_link
    with (
        NetAppClient(url, transport="h264", adapt="auto") as client,
        Camera(client, str(media_dir / "pedestrians.avi")) as camera,
    ):
        wait_until(lambda: len(camera.since(0)) >= 5, 30, "results of the H.264 stream")
        assert client.send_settings.bitrate_kbps == client.adapt_report()["settings"]["bitrate_kbps"] > 0
    assert all(r.sent and r.sent["bitrate_kbps"] for r in camera.since(0))
