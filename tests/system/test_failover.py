"""Several netapps and a fallback on the robot: real netapps on loopback, real links through the link emulator.

Hedging keeps the first result and counts the others; `primary` fails over when its netapp dies (and says so
through `on_error`) and comes back; the fallback answers while the link is down; late results are marked late.
"""

from __future__ import annotations

import threading
import time

import pytest

from bench.linkemu import LinkEmulator, LinkProfile, LinkSchedule, Outages
from netapp.client import NetAppClient
from netapp.client.netapp_client import NetAppError, Switch
from netapp.server.app import create_app
from tests.support.images import make_jpeg
from tests.support.processors import SlowProcessor
from tests.support.servers import BackgroundServer

pytestmark = pytest.mark.timeout(120)
FAST_LINK = LinkProfile("test", 2.0, 0.0, 0.0, None, None)


def stream_until(client: NetAppClient, done, timeout_s: float = 20.0, fps: float = 25.0) -> None:
    """Send frames at `fps` until `done()` holds (a poll with a deadline; the pacing is the robot's)."""
    deadline = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < deadline, "the condition never held"
        client.send(make_jpeg())
        time.sleep(1 / fps)  # pacing the frame rate, not synchronisation


@pytest.mark.parametrize("transport", ["ws", "http"])
def test_hedge_keeps_the_first_result_and_counts_the_others(serve, tiny_detector, transport):
    a, b = serve(tiny_detector), serve(tiny_detector)
    with NetAppClient([a.url, b.url], transport=transport, policy="hedge") as client:
        assert client.link_state == "hedging"
        stream_until(client, lambda: client.stats.results >= 10 and client.stats.discarded >= 5)
        assert client.wait_idle(20)
        results = list(client.results(timeout=0.2))
    assert {r.source for r in results} <= {a.url, b.url}
    timestamps = [r.timestamp for r in results]
    assert len(timestamps) == len(set(timestamps))  # each frame answered once
    assert client.stats.results + client.stats.discarded == client.stats.sent  # every answer counted once
    assert sum(client.stats.by_source.values()) == client.stats.results


def test_primary_fails_over_when_its_netapp_dies_and_tells_the_robot(serve, tiny_detector):
    first = BackgroundServer(create_app(tiny_detector)).start()
    port = int(first.url.rsplit(":", 1)[1])
    second = serve(tiny_detector)
    errors, switches = [], []
    client = NetAppClient(
        [first.url, second.url], transport="ws", on_error=errors.append, on_switch=switches.append
    ).connect()
    try:
        stream_until(client, lambda: client.stats.by_source[first.url] >= 3)
        assert client.link_state == "connected" and client.url == first.url
        first.stop()  # the netapp is killed
        stream_until(client, lambda: client.stats.by_source[second.url] >= 3)
        assert client.url == second.url
        lost = [e for e in errors if e.get("reason") == "disconnected"]
        assert lost and lost[0]["source"] == first.url
        assert "reconnecting" in lost[0]["error"] and second.url in lost[0]["error"]  # what the client does
        assert any(s.urls == (second.url,) for s in switches)
        back = BackgroundServer(create_app(tiny_detector), port=port).start()  # it comes back
        try:
            stream_until(client, lambda: client.url == first.url, timeout_s=40)
            before = client.stats.by_source[first.url]
            stream_until(client, lambda: client.stats.by_source[first.url] >= before + 3)
        finally:
            back.stop()
    finally:
        client.close()
    assert client.stats.switches >= 2


def test_the_fallback_answers_while_the_link_is_down(serve, tiny_detector, tiny_model_path):
    from netapp.models import Detector, DetectorConfig

    server = serve(tiny_detector)
    port = int(server.url.rsplit(":", 1)[1])
    outage = LinkSchedule(outages=Outages(down_s=2.0, every_s=100, first_s=1.5))
    switches: list[Switch] = []
    switched_at: list[int] = []  # the robot's clock (the timestamps of frames) at each switch
    local_frames: list[int] = []

    def on_switch(s: Switch) -> None:
        switches.append(s)
        switched_at.append(time.time_ns())

    def on_result(r) -> None:
        if r.source == "local":
            local_frames.append(r.timestamp)

    with LinkEmulator(FAST_LINK, ("127.0.0.1", port), schedule=outage, mode="userspace") as (host, link_port):
        url = f"http://{host}:{link_port}"
        fallback = Detector(DetectorConfig(str(tiny_model_path)))
        with NetAppClient(
            url, transport="ws", deadline_ms=200, fallback=fallback, on_switch=on_switch, on_result=on_result
        ) as client:
            stream_until(client, lambda: client.stats.by_source["local"] >= 5)  # the link went down
            # The fallback took over the newest frame stuck at the netapp, not only the frames after the switch.
            fell_back = switched_at[[s.state for s in switches].index("fallback")]
            assert local_frames[0] < fell_back and not client.stats.late
            assert client.link_state == "fallback"
            stream_until(client, lambda: client.link_state == "connected")  # the link is back
            local = client.stats.by_source["local"]
            before = client.stats.by_source[url]
            stream_until(client, lambda: client.stats.by_source[url] >= before + 5)
            assert client.stats.by_source["local"] <= local + 2  # no more local processing once back
    states = [s.state for s in switches]
    assert "fallback" in states and states[-1] == "connected"
    assert any(s.local for s in switches)


@pytest.mark.parametrize("transport", ["ws", "http"])
def test_late_results_are_marked_and_deadline_drops_counted(serve, transport):
    slow = SlowProcessor(0.3)
    server = serve(slow)
    results = []
    done = threading.Event()

    def on_result(r):
        results.append(r)
        done.set()

    client = NetAppClient(server.url, transport=transport, deadline_ms=100, on_result=on_result, max_in_flight=1)
    with client:
        client.send(make_jpeg())  # the netapp does not know its time yet: processed, and late
        assert done.wait(20)
        assert results[0].late and results[0].latency_ms > 100
        client.send(make_jpeg())  # now it knows: dropped before inference
        assert client.wait_idle(20)
    assert client.stats.deadline_dropped == 1 and client.stats.late == 1 and slow.calls == 1
    summary = client.stats.summary(1.0)
    assert summary["within_deadline"] == 0 and summary["late"] == 1 and summary["deadline_dropped"] == 1


def test_adaptive_hedges_when_the_first_link_slows_down(serve, tiny_detector):
    from bench.linkemu import Change

    a, b = serve(tiny_detector), serve(tiny_detector)
    port = int(a.url.rsplit(":", 1)[1])
    slows = LinkSchedule(changes=(Change(1.0, delay_ms=150),))
    with LinkEmulator(FAST_LINK, ("127.0.0.1", port), schedule=slows, mode="userspace") as (host, link_port):
        edge = f"http://{host}:{link_port}"
        with NetAppClient([edge, b.url], transport="ws", policy="adaptive", deadline_ms=150) as client:
            stream_until(client, lambda: client.stats.by_source[edge] >= 3)
            assert client.link_state == "connected"
            stream_until(client, lambda: client.link_state == "hedging" and client.stats.by_source[b.url] >= 5)


def test_stream_command_hedges_over_two_netapps(serve, tiny_detector, tmp_path):
    import json

    import cv2
    import numpy as np

    from tests.netapp.test_cli import netapp

    image = tmp_path / "frame.jpg"
    cv2.imwrite(str(image), np.full((120, 160, 3), 70, np.uint8))
    a, b = serve(tiny_detector), serve(tiny_detector)
    common = ["--source", str(image), "--fps", "20", "--duration", "1.5"]
    out = netapp("stream", a.url, b.url, "--policy", "hedge", "--deadline-ms", "2000", "--json", *common)
    assert out.returncode == 0, out.stderr
    summary = json.loads(out.stdout)
    assert set(summary["by_source"]) <= {a.url, b.url} and sum(summary["by_source"].values()) == summary["results"]
    assert summary["discarded"] > 0 and summary["urls"] == [a.url, b.url] and summary["policy"] == "hedge"
    assert summary["within_deadline"] + summary["late"] == summary["results"] >= 10
    human = netapp("stream", a.url, "--deadline-ms", "2000", *common)
    assert human.returncode == 0 and "within" in human.stdout and "by source" in human.stdout
    missing = netapp("stream", a.url, "--fallback-model", str(tmp_path / "nope.onnx"), *common)
    assert missing.returncode == 1 and "--fallback-model" in missing.stderr and "no such file" in missing.stderr


def test_an_unreachable_netapp_is_reported_and_the_others_serve(serve, tiny_detector):
    live = serve(tiny_detector)
    errors = []
    dead = "http://127.0.0.1:9"
    with NetAppClient([dead, live.url], transport="ws", connect_timeout_s=2, on_error=errors.append) as client:
        assert client.link_state == "connected" and client.url == live.url
        stream_until(client, lambda: client.stats.by_source[live.url] >= 3)
    (unreachable,) = [e for e in errors if e.get("reason") == "unreachable"]
    assert unreachable["source"] == dead and "trying again" in unreachable["error"]
    with pytest.raises(NetAppError, match="cannot connect"):
        NetAppClient([dead, dead], transport="ws", connect_timeout_s=2).connect()  # none at all: a clear error


@pytest.mark.parametrize("transport", ["ws", "frames"])
def test_a_move_applies_to_the_netapp_that_asked_for_it(serve, tiny_detector, transport):
    """Two netapps; the second drains and tells the robot to move: only that one is reopened (through its own URL,
    tried again while it refuses), the first keeps its session and answers every frame meanwhile."""
    from netapp.server.settings import Settings

    staying = serve(tiny_detector)
    draining = serve(tiny_detector, Settings(drain_grace_s=30.0))
    switches: list[Switch] = []
    client = NetAppClient([staying.url, draining.url], transport=transport, policy="hedge", on_switch=switches.append)
    with client:
        assert client.link_state == "hedging" and len(switches[-1].urls) == 2
        session = client.session_id
        drained = draining.call(draining.app.drain())
        stream_until(client, lambda: client.stats.moves >= 1 and switches[-1].urls == (staying.url,))
        before = client.stats.by_source[staying.url]
        stream_until(client, lambda: client.stats.by_source[staying.url] >= before + 5)
        assert client.wait_idle(20)
        assert client.session_id == session  # the first netapp's session was not touched
        assert (client.stats.moves, client.stats.errors, client.stats.lost) == (1, 0, 0), client.stats
        assert any("draining" in s.reason for s in switches)
    drained.result(timeout=10)  # the robot's session with the draining netapp is gone: it may exit
