"""Many robots on one netapp at once, over both transports, sharing one model instance."""

from __future__ import annotations

import threading

import requests

from netapp.client import NetAppClient
from tests.support.images import make_jpeg

ROBOTS = 8
FRAMES = 15


def test_eight_robots_at_once_each_get_every_result(tiny_server, tiny_detector):
    loads = []
    original_load = tiny_detector.load
    tiny_detector.load = lambda: loads.append(1) or original_load()
    outcomes: dict[str, tuple[int, int, set]] = {}
    barrier = threading.Barrier(ROBOTS)

    def robot(i: int) -> None:
        transport = "http" if i % 2 else "ws"
        colour = (10 * i, 100, 200 - 10 * i)
        with NetAppClient(tiny_server.url, transport=transport, robot_id=f"robot-{i}", max_in_flight=1) as client:
            barrier.wait(timeout=30)
            sent = set()
            for _ in range(FRAMES):
                sent.add(client.send(make_jpeg(colour=colour)))
                assert client.wait_idle(30)  # one frame at a time: nothing may be dropped
            got = {r.timestamp for r in client.results(timeout=0.5)}
            outcomes[f"robot-{i}"] = (client.stats.results, client.stats.errors, sent - got)

    threads = [threading.Thread(target=robot, args=(i,)) for i in range(ROBOTS)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    assert len(outcomes) == ROBOTS
    for name, (results, errors, missing) in outcomes.items():
        assert (results, errors, missing) == (FRAMES, 0, set()), name
    assert loads == []  # the model loaded once, before the robots came; never per robot
    metrics = requests.get(f"{tiny_server.url}/metrics", timeout=5).text
    assert 'netapp_frames_processed_total{transport="ws"} 60.0' in metrics
    assert 'netapp_frames_processed_total{transport="http"} 60.0' in metrics
    assert 'netapp_frames_dropped_total{transport="ws"} 0.0' in metrics
