"""Many replicas behind one Service: real `netapp serve` processes behind HAProxy (TCP, round robin per connection,
no stickiness, readiness-checked), robots on every transport, a replica drained and one killed mid-stream."""

from __future__ import annotations

import base64
import json
import queue
import signal
import socket
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
import requests
import socketio

from netapp.client.netapp_client import NetAppClient
from netapp.server.cluster.ownership import MAX_ARGS_BYTES, Cluster, check_advertise_url
from tests.support.haproxy import INSTALL_HINT, haproxy_binary
from tests.support.images import make_jpeg
from tests.support.onnx_models import TINY_NAMES
from tests.support.replicas import Replicas

needs_haproxy = pytest.mark.skipif(haproxy_binary() is None, reason=INSTALL_HINT)
FRAME = np.full((96, 128, 3), 90, np.uint8)
RECONNECT_BOUND_S = 5.0  # what a killed replica may cost a robot: detect, reconnect through the balancer, INIT


def wait_for(condition, timeout_s: float = 10.0, what: str = "the condition") -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"{what} did not happen within {timeout_s} s"
        time.sleep(0.02)  # polling with a deadline


@pytest.fixture(scope="module")
def replicas(tiny_model_path) -> Iterator[Replicas]:
    if haproxy_binary() is None:
        pytest.skip(INSTALL_HINT)
    with Replicas(tiny_model_path, count=3, drain_grace_s=10.0) as started:
        yield started


@pytest.fixture
def replaced(replicas) -> Iterator[list[int]]:
    """Replicas a test stops; each is started again (and seen ready by the balancer) afterwards."""
    stopped: list[int] = []
    yield stopped
    for i in stopped:
        if replicas.running(i):
            replicas.stop(i, signal.SIGKILL).wait(10)
        replicas.start(i)
    wait_for(lambda: all(replicas.running(i) for i in range(3)), what="all replicas back")


def token_owner(token: str) -> str:
    body = token.rpartition(".")[0]
    return json.loads(base64.urlsafe_b64decode(body + "=" * (-len(body) % 4)))["o"]


def stream(client: NetAppClient, frames: int) -> None:
    """Send `frames` frames as fast as the client's in-flight bound allows, then wait for the last results."""
    for _ in range(frames):
        client.send(FRAME)
        time.sleep(0.005)  # a robot's frame period (short): the client's newest-wins slot decides what goes out
    assert client.wait_idle(20)


def assert_nothing_lost(client: NetAppClient) -> None:
    stats = client.stats
    assert stats.errors == 0, stats.last_error
    assert stats.lost == 0
    assert stats.results > 0
    assert stats.results + stats.dropped_client + stats.dropped_server == stats.offered


def stream_robots(url: str, robots: int, frames: int, **options) -> None:
    """`robots` NetAppClients (`options`) stream `frames` frames each through `url`, one after another, and lose
    nothing."""
    clients = [NetAppClient(url, **options).connect() for _ in range(robots)]
    try:
        for client in clients:
            stream(client, frames)
            assert_nothing_lost(client)
    finally:
        for client in clients:
            client.close()


# -- every transport through the balancer ------------------------------------------------------------------------


@needs_haproxy
def test_http_robots_are_served_by_any_replica(replicas):
    before = replicas.metrics('netapp_frames_processed_total{transport="http"}')
    stream_robots(replicas.url, 2, 30, transport="http", max_in_flight=2)
    after = replicas.metrics('netapp_frames_processed_total{transport="http"}')
    served_by = [i for i in range(3) if after[i] > before[i]]
    assert len(served_by) >= 2, "each robot's connections should have landed on different replicas"


@needs_haproxy
def test_polled_results_are_kept_by_the_owner_whatever_replica_a_request_lands_on(replicas):
    token = requests.post(f"{replicas.url}/register", json={"robot_id": "poller"}, timeout=5).json()["session_id"]
    owner = replicas.urls.index(token_owner(token))
    before = replicas.metrics('netapp_frames_processed_total{transport="http"}')
    forwarded_before = sum(replicas.metrics('netapp_forwarded_total{kind="http"}'))
    sent = list(range(1, 13))
    for ts in sent:  # a new connection each: round robin puts them on every replica
        headers = {"X-Session-Id": token, "X-Timestamp": str(ts), "Content-Type": "image/jpeg"}
        r = requests.post(f"{replicas.url}/send_image", data=make_jpeg(), headers=headers, timeout=5)
        assert r.status_code == 202, r.text
    got: list[int] = []
    dropped = 0  # superseded by a newer frame in the owner's queue (newest wins), counted by the owner

    def polled_all() -> bool:
        nonlocal dropped
        r = requests.get(f"{replicas.url}/results", headers={"X-Session-Id": token}, timeout=5)
        assert r.status_code == 200, r.text
        got.extend(result["timestamp"] for result in r.json()["results"])
        dropped = r.json()["dropped"]
        return len(got) + dropped >= len(sent)

    wait_for(polled_all, what="every polled result")
    assert len(got) + dropped == len(sent) and len(set(got)) == len(got) and set(got) <= set(sent)
    assert sent[-1] in got  # the newest frame always wins
    after = replicas.metrics('netapp_frames_processed_total{transport="http"}')
    assert [after[i] - before[i] for i in range(3)] == [len(got) if i == owner else 0 for i in range(3)]
    assert sum(replicas.metrics('netapp_forwarded_total{kind="http"}')) > forwarded_before
    assert requests.post(f"{replicas.url}/unregister", headers={"X-Session-Id": token}, timeout=5).ok


@needs_haproxy
@pytest.mark.parametrize("transport", ["ws", "h264"])
def test_socketio_robots_starting_with_long_polling_are_served_by_their_owner(replicas, transport):
    """python-socketio starts with long-polling, then upgrades: the handshake, its polls and posts and the upgrade
    land on different replicas, which forward them to the session's owner."""
    if transport == "h264":
        pytest.importorskip("av", reason="PyAV is not installed (pip install 'netapp[h264]')")
    before = sum(replicas.metrics("netapp_forwarded_total"))
    stream_robots(replicas.url, 3, 30, transport=transport, websocket_first=False)
    assert sum(replicas.metrics("netapp_forwarded_total")) > before, "no request needed forwarding"


@needs_haproxy
def test_netapp_clients_go_straight_to_websocket_and_need_no_forwarding(replicas):
    """NetAppClient's default: one WebSocket per robot, so its session is where its connection landed."""
    before = sum(replicas.metrics("netapp_forwarded_total"))
    served_before = replicas.metrics('netapp_frames_processed_total{transport="ws"}')
    stream_robots(replicas.url, 3, 20, transport="ws")
    assert sum(replicas.metrics("netapp_forwarded_total")) == before, "a WebSocket robot's request was forwarded"
    served = replicas.metrics('netapp_frames_processed_total{transport="ws"}')
    assert sum(served[i] > served_before[i] for i in range(3)) >= 2, "each robot is served where it landed"


@needs_haproxy
def test_robots_going_straight_to_websocket_are_served(replicas):
    results: queue.Queue = queue.Queue()
    robots = []
    for _ in range(3):
        sio = socketio.Client(reconnection=False)
        sio.on("results", results.put, namespace="/data")
        sio.connect(replicas.url, namespaces=["/data", "/control"], transports=["websocket"], wait_timeout=10)
        ok, message = sio.call("command", {"cmd_type": 1, "data": {}}, namespace="/control", timeout=10)
        assert ok, message
        robots.append(sio)
    try:
        for n in range(10):
            for sio in robots:
                sio.emit("image", {"timestamp": n, "frame": make_jpeg()}, namespace="/data")
                assert results.get(timeout=10)["timestamp"] == n
    finally:
        for sio in robots:
            sio.disconnect()


@needs_haproxy
def test_unmodified_era_5g_client_is_served_by_any_replica(replicas):
    era = pytest.importorskip("era_5g_client.client_base", reason="era-5g-client is not installed (make install)")
    from era_5g_interface.channels import CallbackInfoClient, ChannelType

    robots = []
    try:
        for _ in range(2):
            got: queue.Queue = queue.Queue()
            client = era.NetAppClientBase({"results": CallbackInfoClient(ChannelType.JSON, got.put)})
            client.register(replicas.url, args={"robot": "era"})
            assert client.initialized
            robots.append((client, got))
        for _ in range(15):
            for client, got in robots:
                ts = time.perf_counter_ns()
                client.send_image(FRAME, "image", ChannelType.JPEG, ts)
                result = got.get(timeout=10)
                assert result["timestamp"] == ts
                assert result["detections"][0]["class_name"] == TINY_NAMES[2]
    finally:
        for client, _ in robots:  # see test_socketio: python-engineio's threaded disconnect can stall (upstream)
            threading.Thread(target=client.disconnect, daemon=True).start()


# -- a replica going away mid-stream ------------------------------------------------------------------------------


class StreamingRobot:
    """A NetAppClient streaming at a steady pace from its own thread, noting when each result arrives."""

    PERIOD_S = 0.02

    def __init__(self, url: str, transport: str) -> None:
        self.arrivals: list[float] = []
        self.client = NetAppClient(url, transport=transport, on_result=lambda r: self.arrivals.append(time.monotonic()))
        self.client.connect()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self.PERIOD_S):
            self.client.send(FRAME)

    def results_after(self, moment: float) -> int:
        return sum(1 for t in list(self.arrivals) if t > moment)

    def first_result_after(self, moment: float) -> float | None:
        return next((t for t in list(self.arrivals) if t > moment), None)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.client.wait_idle(10)
        self.client.close()


@pytest.fixture
def robots(replicas) -> Iterator[list[StreamingRobot]]:
    transports = ["ws", "ws", "http", "http", "frames"]
    try:
        import av  # noqa: F401

        transports.append("h264")
    except ImportError:
        pass
    started = [StreamingRobot(replicas.url, t) for t in transports]
    try:
        wait_for(lambda: all(len(r.arrivals) >= 5 for r in started), what="every robot's first results")
        yield started
    finally:
        for robot in started:
            robot.stop()


def busiest_socketio_replica(replicas: Replicas) -> int:
    """The replica that owns the most WebSocket sessions (those it must move or lose)."""
    counts = [
        sum(per_transport)
        for per_transport in zip(
            replicas.metrics('netapp_active_sessions{transport="ws"}'),
            replicas.metrics('netapp_active_sessions{transport="h264"}'),
            replicas.metrics('netapp_active_sessions{transport="frames"}'),
            strict=True,
        )
    ]
    return counts.index(max(counts))


@needs_haproxy
def test_a_drained_replica_moves_its_robots_losing_only_frames_in_flight(replicas, replaced, robots):
    victim = busiest_socketio_replica(replicas)
    replaced.append(victim)
    started = time.monotonic()
    process = replicas.stop(victim, signal.SIGTERM)
    assert process.wait(replicas.drain_grace_s + 10) == 0
    drained_s = time.monotonic() - started
    assert drained_s < replicas.drain_grace_s, f"drained after {drained_s:.1f} s: {replicas.log(victim)}"
    exited = time.monotonic()
    wait_for(lambda: all(r.results_after(exited) >= 5 for r in robots), what="results after the drain")
    for robot in robots:
        robot.stop()
    for robot in robots:
        stats = robot.client.stats
        assert stats.errors == 0, (robot.client.transport, stats.last_error)
        assert stats.lost <= robot.client.max_in_flight * max(1, stats.moves), (robot.client.transport, stats)
    assert sum(r.client.stats.moves for r in robots) >= 1, "no robot was told to move"


@needs_haproxy
def test_a_killed_replica_costs_its_robots_at_most_the_reconnect_time(replicas, replaced, robots):
    victim = busiest_socketio_replica(replicas)
    replaced.append(victim)
    killed = time.monotonic()
    replicas.stop(victim, signal.SIGKILL).wait(10)
    wait_for(lambda: all(r.results_after(killed) >= 3 for r in robots), RECONNECT_BOUND_S + 5, "results after the kill")
    for robot in robots:
        gap = robot.first_result_after(killed) - killed
        assert gap <= RECONNECT_BOUND_S, f"{robot.client.transport} robot had no result for {gap:.1f} s"


# -- no forwarding to an address a signature does not vouch for ---------------------------------------------------


@needs_haproxy
def test_forged_ids_are_never_forwarded(replicas):
    with socket.socket() as trap:  # where a forged id points: it must never be connected to
        trap.bind(("127.0.0.1", 0))
        trap.listen()
        trap.settimeout(0.5)
        address = f"http://127.0.0.1:{trap.getsockname()[1]}"
        owner = base64.urlsafe_b64encode(address.encode()).rstrip(b"=").decode()
        forged_sid = f"AAAAAAAAAAAAAAAAAAAA.{owner}.{'A' * 22}"
        forged_token = Cluster.build(b"k" * 32, address).session_token("evil", {})
        for url in replicas.urls:
            r = requests.get(f"{url}/socket.io/", params={"EIO": 4, "transport": "polling", "sid": forged_sid})
            assert r.status_code == 400
            r = requests.get(f"{url}/results", headers={"X-Session-Id": forged_token}, timeout=5)
            assert r.status_code == 404 and r.json()["reason"] == "unknown_session"
        with pytest.raises(TimeoutError):
            trap.accept()


# -- the ids (pure) -------------------------------------------------------------------------------------------------


def test_session_tokens_carry_the_session_and_its_owner_and_refuse_tampering():
    a = Cluster.build(b"s" * 32, "http://10.0.0.1:5896/")
    b = Cluster.build(b"s" * 32, "http://10.0.0.2:5896")
    token = a.session_token("robot-1", {"conf": 0.5})
    claims = b.open_session_token(token)
    assert (claims.owner, claims.robot_id, claims.args) == ("http://10.0.0.1:5896", "robot-1", {"conf": 0.5})
    assert b.remote(claims.owner) == "http://10.0.0.1:5896" and a.remote(claims.owner) is None
    body, _, signature = token.rpartition(".")
    tampered = base64.urlsafe_b64encode(json.dumps({"o": "http://evil", "a": {}}).encode()).decode().rstrip("=")
    for bad in (f"{tampered}.{signature}", f"{body}.{'A' * len(signature)}", "", "x", body):
        assert b.open_session_token(bad) is None
    assert Cluster.build(b"t" * 32, "http://10.0.0.1:5896").open_session_token(token) is None
    with pytest.raises(ValueError, match="limit"):
        a.session_token(None, {"big": "x" * MAX_ARGS_BYTES})


def test_engineio_ids_name_their_owner_only_with_a_shared_key():
    alone = Cluster.build(None, None)
    assert alone.engineio_sid("abc") == "abc" and alone.engineio_owner("abc") is None
    a = Cluster.build(b"s" * 32, "http://10.0.0.1:5896")
    sid = a.engineio_sid("abc")
    assert Cluster.build(b"s" * 32, "http://10.0.0.2:5896").engineio_owner(sid) == "http://10.0.0.1:5896"
    assert Cluster.build(b"t" * 32, "http://10.0.0.2:5896").engineio_owner(sid) is None
    for bad in ("ftp://x", "http://", "10.0.0.1:5896", "http://x:1/path"):
        with pytest.raises(ValueError, match="advertise-url"):
            check_advertise_url(bad)
    with pytest.raises(ValueError, match="advertise-url"):
        Cluster.build(b"s" * 32, None)


# -- draining, in one process ---------------------------------------------------------------------------------------


@pytest.fixture
def draining_server(serve, tiny_detector):
    from netapp.server.settings import Settings

    return serve(tiny_detector, Settings(drain_grace_s=30.0))


def test_a_draining_replica_takes_no_new_robots_tells_its_robots_to_move_and_waits_for_them(draining_server):
    url, app = draining_server.url, draining_server.app
    moves: queue.Queue = queue.Queue()
    robot = socketio.Client(reconnection=False)
    robot.on("move", moves.put, namespace="/control")
    robot.connect(url, namespaces=["/data", "/control"], wait_timeout=10)
    token = requests.post(f"{url}/register", json={}, timeout=5).json()["session_id"]
    poller = requests.post(f"{url}/register", json={}, timeout=5).json()["session_id"]
    headers = {"X-Session-Id": poller, "Content-Type": "image/jpeg", "X-Timestamp": "7"}
    assert requests.post(f"{url}/send_image", data=make_jpeg(), headers=headers, timeout=5).status_code == 202
    wait_for(lambda: app.services.sessions.get(poller).results, what="the polled result")

    drained = draining_server.call(app.drain())
    assert moves.get(timeout=5)["reason"] == "draining"
    ready = requests.get(f"{url}/readyz", timeout=5)
    assert ready.status_code == 503 and ready.json()["reason"] == "draining"
    register = requests.post(f"{url}/register", json={}, timeout=5)
    assert register.status_code == 503 and register.json()["reason"] == "draining"
    assert register.headers["Retry-After"] == "1" and register.headers["Connection"] == "close"
    with pytest.raises(socketio.exceptions.ConnectionError):  # a new robot is sent elsewhere
        socketio.Client(reconnection=False).connect(url, namespaces=["/data"], wait_timeout=5)
    headers = {"X-Session-Id": token, "Content-Type": "image/jpeg"}
    waited = requests.post(f"{url}/send_image?wait=true", data=make_jpeg(), headers=headers, timeout=5)
    assert waited.status_code == 200 and waited.headers["Connection"] == "close"  # served, then off elsewhere
    queued = requests.post(f"{url}/send_image", data=make_jpeg(), headers=headers, timeout=5)
    assert queued.status_code == 503 and queued.json()["reason"] == "draining" and queued.headers["Retry-After"]

    assert not drained.done(), "a robot is still connected and a polled result is still to fetch"
    robot.disconnect()
    polled = requests.get(f"{url}/results", headers={"X-Session-Id": poller}, timeout=5).json()["results"]
    assert [r["timestamp"] for r in polled] == [7]
    drained.result(timeout=10)  # everything has moved: the replica may exit


def test_draining_ends_with_the_grace_period_when_robots_stay(serve, tiny_detector):
    from netapp.server.settings import Settings

    server = serve(tiny_detector, Settings(drain_grace_s=0.3))
    robot = socketio.Client(reconnection=False)  # ignores `move`, as an unmodified era-5g-client does
    robot.connect(server.url, namespaces=["/data", "/control"], wait_timeout=10)
    try:
        started = time.monotonic()
        server.call(server.app.drain()).result(timeout=10)
        assert 0.3 <= time.monotonic() - started < 5
        assert robot.connected  # not cut off by the drain itself: the shutdown after it closes the connection
    finally:
        robot.disconnect()


def test_serve_says_what_a_replica_needs(tmp_path, tiny_model_path, monkeypatch):
    from netapp.protocol import CLUSTER_KEY_ENV
    from netapp.server.cli import cluster_key
    from tests.netapp.test_cli import netapp

    key = tmp_path / "key"
    key.write_text("")
    with pytest.raises(ValueError, match="is empty"):
        cluster_key(str(key))
    monkeypatch.setenv(CLUSTER_KEY_ENV, " from-a-secret ")
    assert cluster_key(None) == b"from-a-secret"
    key.write_text("k" * 64)
    answer = netapp("serve", "--model", str(tiny_model_path), "--cluster-key-file", str(key))
    assert answer.returncode == 2 and "--advertise-url http://POD_IP:PORT" in answer.stderr


def test_which_http_requests_go_to_the_session_owner():
    from netapp.server.cluster.replica import needs_owner

    assert needs_owner("/results", {}) and needs_owner("/unregister", {})
    assert needs_owner("/send_image", {}) and needs_owner("/send_image", {"wait": ["false"]})
    assert not needs_owner("/send_image", {"wait": ["true"]})  # processed where it lands, answered inline
    assert needs_owner("/send_image", {"wait": ["true"]}, stateful=True)  # the session's state lives with its owner
    assert not needs_owner("/register", {}) and not needs_owner("/readyz", {})
