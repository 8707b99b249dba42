"""The netapp's live pages in a real headless browser (Debian's chromium driven by Playwright): a robot streams
dog.jpg, /ui lists it, its page draws the dog's box where YOLOX found it and keeps updating; frames are kept and
encoded only while a page is open. Plus the pure parts: the robot's latency report is bounded and checked."""

from __future__ import annotations

import json
import threading

import cv2
import numpy as np
import pytest
import requests

from netapp.client import NetAppClient
from netapp.client.draw import class_colour
from netapp.server.ui.live import LiveView, robot_latency
from tests.support.polling import wait_until

DOG = 16


def test_robot_latency_reports_are_checked():
    assert robot_latency({"uplink_ms": 1.5, "downlink_ms": 2}) == (1.5, 2.0)
    assert robot_latency('{"uplink_ms": 1, "downlink_ms": 3}') == (1.0, 3.0)
    for bad in (
        None,
        [],
        "x" * 300,
        "{",
        {"uplink_ms": -1, "downlink_ms": 2},
        {"uplink_ms": float("nan"), "downlink_ms": 1},
        {"uplink_ms": True, "downlink_ms": 1},
        {"uplink_ms": 1e12, "downlink_ms": 1},
    ):
        assert robot_latency(bad) is None, bad


def test_nothing_is_kept_for_a_robot_nobody_watches():
    from netapp.server.sessions import SessionRegistry

    session = SessionRegistry(10).create("ws", robot_id="r1")
    live = LiveView()
    message = {
        "timestamp": 1,
        "recv_timestamp": 0,
        "timestamp_before_process": 2_000_000,
        "timestamp_after_process": 12_000_000,
        "send_timestamp": 13_000_000,
    }
    live.report(session, {"uplink_ms": 4.0, "downlink_ms": 6.0})
    live.record(session, message, np.zeros((4, 4, 3), np.uint8))
    (view,) = live.robots()
    assert view.latest is None and not live.watched(session.id)
    assert view.history[-1]["queue_ms"] == 2 and view.history[-1]["inference_ms"] == 10
    assert view.history[-1]["total_ms"] == 4 + 2 + 10 + 6
    live.watch(view)
    live.record(session, message, np.zeros((4, 4, 3), np.uint8))
    assert view.latest is not None and live.watched(session.id)
    live.unwatch(view)
    assert view.latest is None
    live.forget(session.id)
    assert live.robots() == [] and live.get(view.id) is None


def canvas_pixels(page, x: int, y: int, width: int) -> list[list[int]]:
    """RGBA of `width` pixels from (x, y) of the page's frame canvas."""
    script = "([x, y, w]) => Array.from(document.getElementById('frame').getContext('2d')" + (
        ".getImageData(x, y, w, 1).data)"
    )
    data = page.evaluate(script, [x, y, width])
    return [data[i : i + 4] for i in range(0, len(data), 4)]


def colour_distance(rgba: list[int], rgb: tuple[int, int, int]) -> int:
    return max(abs(a - b) for a, b in zip(rgba[:3], rgb, strict=True))


class Robot:
    """A robot streaming one image at 10 fps from a thread, until stopped."""

    def __init__(self, url: str, image: np.ndarray, robot_id: str) -> None:
        self.client = NetAppClient(url, transport="ws", robot_id=robot_id).connect()
        self.image = image
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.wait(0.1):  # the robot's frame rate
            self.client.send(self.image)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)
        self.client.close()


def test_the_robot_page_draws_the_dog_live(chromium, serve, real_model_path, media_dir):
    from netapp.models import Detector, DetectorConfig

    server = serve(Detector(DetectorConfig(str(real_model_path))))
    live = server.app.other_asgi_app.state.live
    robot = Robot(server.url, cv2.imread(str(media_dir / "dog.jpg")), "dog-bot")
    page = chromium.new_page()
    try:
        wait_until(lambda: robot.client.stats.results >= 3, what="results")
        (view,) = live.robots()
        assert view.watchers == 0 and view.latest is None and view.encoded is None  # nobody looks: nothing kept

        page.goto(server.url + "/ui")
        row = page.locator("#robots tbody tr", has_text="dog-bot")
        row.wait_for(timeout=15_000)
        assert row.locator("td").nth(1).inner_text() == "ws"
        row.locator("a").click()
        page.wait_for_function("Number(document.body.dataset.frames) >= 1", timeout=20_000)
        assert view.watchers == 1

        dog = page.locator("#detections li[data-class='16']").first
        x1, y1, x2, y2 = (round(v) for v in json.loads(dog.get_attribute("data-bbox")))
        assert dog.inner_text().startswith("dog ")
        b, g, r = class_colour(DOG)
        for y in range(y1 + (y2 - y1) // 4, y2 - (y2 - y1) // 4, 7):  # along the left and right edges
            for x in (x1, x2):
                assert min(colour_distance(p, (r, g, b)) for p in canvas_pixels(page, x - 2, y, 5)) <= 6, (x, y)
        inside = canvas_pixels(page, (x1 + x2) // 2, (y1 + y2) // 2, 1)[0]
        assert colour_distance(inside, (r, g, b)) > 30  # the box is an outline on the picture

        reported = wait_until(lambda: view.history and view.history[-1]["uplink_ms"] is not None, what="a report")
        assert reported and view.history[-1]["downlink_ms"] >= 0  # NetAppClient tells its uplink and downlink
        first = page.evaluate("document.body.dataset.timestamp")
        page.wait_for_function(f"document.body.dataset.timestamp !== '{first}'", timeout=10_000)  # live
        assert "results/s" in page.locator("#stats").inner_text()
        chart = page.evaluate(
            "Array.from(document.getElementById('chart').getContext('2d').getImageData(0, 0, 640, 200).data)"
        )
        assert any(chart[3::4]), "the latency chart has bars"
    finally:
        page.close()
        wait_until(lambda: view.watchers == 0, what="the page to let go")
        assert view.latest is None and view.encoded is None  # the page went: no frame held
        robot.close()
    wait_until(lambda: not live.robots(), what="the robot to leave the list")
    assert requests.get(server.url + "/ui/api/robots", timeout=5).json() == {"robots": []}


def test_pages_are_served_offline_and_docs_are_off(tiny_server):
    for path in ("/ui", "/ui/robot/abc", "/ui/static/ui.js", "/ui/static/ui.css"):
        response = requests.get(tiny_server.url + path, timeout=5)
        assert response.status_code == 200, path
        assert "http://" not in response.text and "https://" not in response.text, f"{path} loads something remote"
    assert requests.get(tiny_server.url + "/ui/static/..%2Fapp.py", timeout=5).status_code == 404
    assert requests.get(tiny_server.url + "/ui/api/robots/nope", timeout=5).status_code == 404
    assert requests.get(tiny_server.url + "/docs", timeout=5).status_code == 404
    assert requests.get(tiny_server.url + "/openapi.json", timeout=5).status_code == 200


def test_an_http_robot_reports_its_uplink_and_downlink(tiny_server, jpeg):
    live = tiny_server.app.other_asgi_app.state.live
    with NetAppClient(tiny_server.url, transport="http", robot_id="http-bot") as client:
        for _ in range(3):
            client.send(jpeg)
            assert client.wait_idle(10)
        (view,) = live.robots()
        entry = view.history[-1]
        assert entry["uplink_ms"] is not None and entry["downlink_ms"] is not None
        assert view.summary()["robot_id"] == "http-bot" and view.summary()["transport"] == "http"


@pytest.mark.parametrize("transport", ["ws", "http"])
def test_a_hedging_robot_reports_to_each_netapp_its_own_latency(serve, tiny_detector, jpeg, transport):
    """With several netapps each has its own clock offset estimate and page report (one netapp's figures would be
    wrong for another's clock)."""
    a, b = serve(tiny_detector), serve(tiny_detector)
    with NetAppClient([a.url, b.url], transport=transport, robot_id="hedge-bot", policy="hedge") as client:
        for _ in range(4):
            client.send(jpeg)
            assert client.wait_idle(10)
        results = list(client.results(timeout=0.2))
        netapps = client._links
        assert all(n.clock.offset_ns is not None and n.clock is not netapps[0].clock for n in netapps[1:])
        for server in (a, b):
            (view,) = server.app.other_asgi_app.state.live.robots()
            entry = view.history[-1]
            assert entry["uplink_ms"] is not None and entry["downlink_ms"] is not None
    assert results and all(r.breakdown is not None and r.source in (a.url, b.url) for r in results)


def test_a_netapp_with_a_token_shows_its_robots_only_with_it(serve, tiny_detector):
    from netapp.server.access import token_digest
    from netapp.server.settings import Settings

    server = serve(tiny_detector, Settings(token_sha256=token_digest("s3cret-token")))
    api = server.url + "/ui/api/robots"
    assert requests.get(api, timeout=5).status_code == 401
    assert requests.get(api, params={"token": "wrong"}, timeout=5).status_code == 401
    assert requests.get(api, params={"token": "s3cret-token"}, timeout=5).json() == {"robots": []}
    assert requests.get(api, headers={"Authorization": "Bearer s3cret-token"}, timeout=5).status_code == 200
    assert requests.get(server.url + "/ui/api/robots/x/events", timeout=5).status_code == 401


@pytest.mark.parametrize("transport", ["ws", "http"])
def test_the_page_shows_what_a_robot_sends_now(tiny_server, transport):
    """Frame size and KB per frame as they arrive: a robot that sends smaller frames shows smaller figures."""
    big = cv2.imencode(".jpg", np.random.default_rng(1).integers(0, 255, (480, 640, 3), np.uint8))[1].tobytes()
    small = cv2.imencode(".jpg", np.zeros((120, 160, 3), np.uint8))[1].tobytes()
    api = tiny_server.url + "/ui/api/robots"
    with NetAppClient(tiny_server.url, transport=transport, robot_id="sizes") as client:
        client.send(big)
        assert client.wait_idle(10)
        (robot,) = requests.get(api, timeout=5).json()["robots"]
        assert robot["frame_size"] == "640x480" and robot["kb_per_frame"] == round(len(big) / 1000, 1)
        for _ in range(30):
            client.send(small)
            assert client.wait_idle(10)
        (robot,) = requests.get(api, timeout=5).json()["robots"]
        assert robot["frame_size"] == "160x120" and robot["kb_per_frame"] < 0.1 * len(big) / 1000
