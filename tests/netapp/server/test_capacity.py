"""Capacity: the pure estimator, its figures in /metrics, /capacity and the 5G-ERA heartbeat, and the refusal of a
robot past the hard limit (503 + Retry-After on /register, a refused INIT on Socket.IO) where the deployment chose
`--admission measured`, and none by default or on a cold estimate."""

from __future__ import annotations

import json
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest
import requests
import socketio

from netapp.protocol import COMMAND_EVENT, CONTROL_NAMESPACE, DATA_NAMESPACE, NEEDS_FIELD, CommandType
from netapp.sdk import Processor
from netapp.server.capacity import CapacityEstimator, InputRate
from netapp.server.sessions import SessionRegistry
from netapp.server.settings import Settings
from tests.support.images import make_jpeg

# -- the estimator (pure) -------------------------------------------------------------------------------------------


def test_no_limits_before_the_first_batch():
    limits = CapacityEstimator().limits([25.0])
    assert (limits.capacity_fps, limits.optimal, limits.hard, limits.measured) == (None, None, None, False)


def test_limits_from_capacity_and_the_median_robot_rate():
    estimator = CapacityEstimator(headroom=0.9, hard_share=0.5)
    estimator.observe_batch(1, 0.0125)  # 80 results/s
    limits = estimator.limits([25.0, 25.0, 10.0])
    assert limits.capacity_fps == pytest.approx(80.0)
    assert limits.demand_fps == 25.0
    assert limits.optimal == 2  # floor(80 * 0.9 / 25)
    assert limits.hard == 6  # floor(80 / 12.5): each robot still gets half its frames
    assert limits.measured


def test_the_best_batch_size_sets_capacity():
    estimator = CapacityEstimator()
    estimator.observe_batch(1, 0.010)  # 100/s
    estimator.observe_batch(4, 0.020)  # 200/s
    assert estimator.capacity_fps() == pytest.approx(200.0)


def test_batch_times_are_a_moving_average():
    estimator = CapacityEstimator(alpha=0.5)
    estimator.observe_batch(1, 0.010)
    estimator.observe_batch(1, 0.030)  # 0.010 + 0.5 * 0.020
    assert estimator.capacity_fps() == pytest.approx(50.0)
    estimator.observe_batch(1, float("nan"))  # ignored, as are empty batches and non-positive times
    estimator.observe_batch(0, 0.1)
    estimator.observe_batch(1, 0.0)
    assert estimator.capacity_fps() == pytest.approx(50.0)


def test_default_rate_until_robots_stream_and_then_no_refusal_on_a_guess():
    estimator = CapacityEstimator(default_robot_fps=10.0, min_batches=1)
    estimator.observe_batch(1, 0.05)  # 20/s
    limits = estimator.limits([])
    assert (limits.demand_fps, limits.optimal, limits.hard, limits.measured) == (10.0, 1, 4, False)
    assert estimator.admission_limit([]) is None
    assert estimator.admission_limit([10.0]) == 4


def test_a_cold_estimate_refuses_nobody():
    estimator = CapacityEstimator(min_batches=3)
    for batch in range(3):
        assert estimator.admission_limit([25.0]) is None, f"refused on {batch} batches"
        estimator.observe_batch(1, 0.1)  # 10/s: one robot at 25 FPS is past half its rate
    assert estimator.admission_limit([25.0]) == 1


def test_a_robot_that_says_what_it_needs_counts_at_that_rate():
    registry = SessionRegistry(10)
    registry.create("ws", args={NEEDS_FIELD: 2})  # its camera may run at 25 FPS: it needs 2 results a second
    streaming = registry.create("http")
    for t in range(5):
        streaming.rate.arrived(t * 0.04)  # a 25 FPS camera, no need stated
    assert sorted(registry.input_rates(0.2)) == pytest.approx([2.0, 25.0])
    registry.create("ws", args={NEEDS_FIELD: "lots"})  # not a number: ignored, counted by its frames once it streams
    assert len(registry.input_rates(0.2)) == 2


def test_a_greedy_robot_counts_as_a_camera():
    estimator = CapacityEstimator(max_robot_fps=30.0)
    estimator.observe_batch(1, 0.01)
    assert estimator.limits([500.0]).demand_fps == 30.0


def test_the_hard_limit_never_below_the_optimal_and_off_at_zero_share():
    estimator = CapacityEstimator(hard_share=0.99, headroom=1.0)
    estimator.observe_batch(1, 0.01)  # 100/s
    limits = estimator.limits([30.0])
    assert limits.optimal == limits.hard == 3
    assert CapacityEstimator(hard_share=0.0).limits([30.0]).hard is None
    off = CapacityEstimator(hard_share=0.0)
    off.observe_batch(1, 0.01)
    assert off.limits([30.0]).hard is None and off.admission_limit([30.0]) is None


def test_input_rate_from_arrivals():
    rate = InputRate(alpha=0.5)
    assert rate.fps(0.0) is None
    rate.arrived(10.0)
    assert rate.fps(10.0) is None  # one frame: no interval yet
    rate.arrived(10.1)
    assert rate.fps(10.1) == pytest.approx(10.0)
    rate.arrived(10.1)  # same instant: no interval
    rate.arrived(10.15)  # 0.1 + 0.5 * (0.05 - 0.1)
    assert rate.fps(10.15) == pytest.approx(1 / 0.075)
    assert rate.fps(20.0) is None  # silent for longer than stale_s: no longer streaming


# -- served ---------------------------------------------------------------------------------------------------------


class Slow(Processor):
    """About 10 results per second at most: a capacity small enough to reach with two robots."""

    name = "slow"

    def prepare(self, image, args):
        return image.shape

    def process(self, batch):
        time.sleep(0.1)
        return [{"shape": list(shape)} for shape in batch]


def _register(url: str) -> requests.Response:
    return requests.post(f"{url}/register", json={"robot_id": "r"}, timeout=10)


def _stream_until_measured(url: str, session_id: str) -> dict:
    """Send frames (faster than 30 FPS, so counted as a 30 FPS camera) until the capacity is measured."""
    headers = {"X-Session-Id": session_id, "Content-Type": "image/jpeg"}
    frame = make_jpeg()
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        for _ in range(3):
            assert requests.post(f"{url}/send_image", data=frame, headers=headers, timeout=10).status_code == 202
        capacity = requests.get(f"{url}/capacity", timeout=10).json()
        if capacity["measured"]:
            return capacity
    raise AssertionError("the capacity was never measured")


def _init(url: str) -> tuple[socketio.Client, tuple]:
    client = socketio.Client()
    client.connect(url, namespaces=[DATA_NAMESPACE, CONTROL_NAMESPACE], transports=["websocket"], wait_timeout=10)
    ack = client.call(COMMAND_EVENT, {"cmd_type": CommandType.INIT, "data": {}}, namespace=CONTROL_NAMESPACE)
    return client, ack


def test_past_the_hard_limit_a_new_robot_is_refused_on_both_transports(serve):
    # one batch at a time: the capacity is the processor's 10/s; refusing at the hard limit is the deployment's choice
    server = serve(Slow(), Settings(lanes=1, admission="measured", warm_batches=1))
    first = _register(server.url).json()["session_id"]
    capacity = _stream_until_measured(server.url, first)
    # at most 10 results/s for robots at 30 FPS: one robot is all it can take at half its rate
    assert capacity["capacity_fps"] <= 10.5
    assert capacity["demand_fps"] == 30.0
    assert (capacity["optimalLimit"], capacity["hardLimit"], capacity["currentRobotsCount"]) == (1, 1, 1)

    refused = _register(server.url)
    assert refused.status_code == 503
    assert refused.headers["Retry-After"] == "5"
    assert refused.json()["reason"] == "sessions_full"
    assert "limit of 1 sessions (its measured capacity)" in refused.json()["error"]

    client, ack = _init(server.url)
    try:
        assert ack[0] is False and "limit of 1 sessions (its measured capacity)" in ack[1]
    finally:
        client.disconnect()

    assert requests.post(f"{server.url}/unregister", headers={"X-Session-Id": first}, timeout=10).ok
    assert _register(server.url).status_code == 201  # room again once the robot left
    metrics = requests.get(f"{server.url}/metrics", timeout=10).text
    assert 'netapp_capacity_robots{kind="hard"} 1.0' in metrics
    assert 'netapp_capacity_robots{kind="optimal"} 1.0' in metrics
    assert "netapp_robots_per_replica 1.0" in metrics


def test_by_default_robots_past_the_measured_limit_are_admitted_and_share(serve):
    server = serve(Slow(), Settings(lanes=1, warm_batches=1))  # admission open, the default
    first = _register(server.url).json()["session_id"]
    capacity = _stream_until_measured(server.url, first)
    assert capacity["hardLimit"] == 1  # still measured and published
    assert _register(server.url).status_code == 201
    client, ack = _init(server.url)
    try:
        assert tuple(ack) == (True, "initialized")
    finally:
        client.disconnect()
    assert requests.get(f"{server.url}/capacity", timeout=10).json()["currentRobotsCount"] >= 2


def test_no_refusal_when_the_hard_limit_is_off(serve):
    server = serve(Slow(), Settings(hard_share=0, lanes=1))
    first = _register(server.url).json()["session_id"]
    capacity = _stream_until_measured(server.url, first)
    assert capacity["hardLimit"] is None and capacity["optimalLimit"] == 1
    assert _register(server.url).status_code == 201


def test_metrics_publish_the_capacity(tiny_server):
    before = requests.get(f"{tiny_server.url}/metrics", timeout=10).text
    assert 'netapp_capacity_robots{kind="optimal"} NaN' in before  # nothing measured yet
    assert "netapp_robots_per_replica 0.0" in before
    session = _register(tiny_server.url).json()["session_id"]
    headers = {"X-Session-Id": session, "Content-Type": "image/jpeg"}
    assert requests.post(f"{tiny_server.url}/send_image?wait=true", data=make_jpeg(), headers=headers, timeout=10).ok
    metrics = {
        line.split(" ")[0]: float(line.split(" ")[1])
        for line in requests.get(f"{tiny_server.url}/metrics", timeout=10).text.splitlines()
        if line and not line.startswith("#")
    }
    assert metrics["netapp_capacity_results_per_second"] > 0
    assert metrics['netapp_capacity_robots{kind="optimal"}'] >= 1
    assert metrics['netapp_capacity_robots{kind="hard"}'] >= metrics['netapp_capacity_robots{kind="optimal"}']
    assert metrics["netapp_robots_per_replica"] == 1
    assert metrics["netapp_result_latency_seconds"] > 0
    assert metrics["netapp_robot_input_fps"] == 10.0  # one frame: no rate yet, the assumed one


class _Middleware(BaseHTTPRequestHandler):
    received: list[dict] = []
    arrived = threading.Event()

    def do_POST(self):  # noqa: N802 (http.server's name)
        body = self.rfile.read(int(self.headers["Content-Length"]))
        if self.path == "/status/netapp":
            type(self).received.append(json.loads(body))
            type(self).arrived.set()
        self.send_response(200)
        self.end_headers()

    def log_message(self, *args):
        pass


def test_the_heartbeat_reaches_the_middleware(serve, tiny_detector):
    middleware = ThreadingHTTPServer(("127.0.0.1", 0), _Middleware)
    threading.Thread(target=middleware.serve_forever, daemon=True).start()
    try:
        address = f"http://127.0.0.1:{middleware.server_address[1]}"
        server = serve(tiny_detector, Settings(middleware_address=address, netapp_id="id-1", netapp_name="detector"))
        _register(server.url)
        deadline = time.monotonic() + 10
        while not any(beat["currentRobotsCount"] == 1 for beat in _Middleware.received):
            _Middleware.arrived.clear()
            assert _Middleware.arrived.wait(max(0.0, deadline - time.monotonic())), "no heartbeat counting the robot"
        beat = _Middleware.received[-1]
        assert set(beat) == {"id", "name", "currentRobotsCount", "optimalLimit", "hardLimit"}
        assert (beat["id"], beat["name"], beat["currentRobotsCount"]) == ("id-1", "detector", 1)
    finally:
        middleware.shutdown()
