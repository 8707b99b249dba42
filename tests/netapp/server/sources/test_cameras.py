"""Cameras the netapp pulls, end to end: a real RTSP camera (GStreamer's RTSP server from Debian, its own process),
PyAV on a real netapp on loopback, results to a real subscriber (`netapp watch`'s Subscription over `frames`)."""

from __future__ import annotations

import contextlib
import json
import logging
import threading
import time

import psutil
import pytest
import requests
import socketio

from netapp.client.errors import NetAppRefused
from netapp.protocol import CONTROL_NAMESPACE, DATA_NAMESPACE, CommandType
from netapp.serve_process import free_port
from netapp.server.settings import Settings
from netapp.server.sources import watchers
from netapp.server.sources.naming import parse_source
from netapp.server.sources.watchers import MAX_PER_ADDRESS, MAX_PER_CAMERA
from tests.netapp.server.test_frames import metric
from tests.support.fake_cameras import HostileCamera
from tests.support.polling import wait_until
from tests.support.rtsp_camera import RtspCamera
from tests.support.watcher import Watcher

OUTAGE_S = 10.0  # the goal: a camera away this long
RESUME_BOUND_S = 5.0  # results resume within this after it is back (measured: bench/cameras.py, docs/cameras.md)
READER_LOG = "netapp.server.sources.reader"


def settings_for(*sources: str, **more) -> Settings:
    return Settings(lanes=1, sources=tuple(parse_source(s) for s in sources), **more)


def camera_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name.startswith("netapp-camera-")]


def sockets_to(port: int) -> list:
    return [c for c in psutil.Process().net_connections(kind="inet") if c.raddr and c.raddr.port == port]


def udp_sockets() -> int:
    return len(psutil.Process().net_connections(kind="udp"))


def test_a_camera_away_for_10_s_gives_results_again_soon_after_it_is_back_and_leaves_nothing_behind(
    cameras, serve, tiny_detector, caplog
):
    caplog.set_level(logging.INFO, logger=READER_LOG)
    camera = cameras()
    udp_before = udp_sockets()
    server = serve(tiny_detector, settings_for(f"door={camera.url}"))
    with Watcher(server.url, "door") as watcher:
        wait_until(lambda: watcher.count() >= 5, 30, "the camera's first results")
        first = watcher.got[0][1]
        assert first["source"] == "door" and isinstance(first["detections"], list)
        assert first["timestamp"] <= time.time_ns()  # when the netapp decoded the picture, ns since the epoch
        assert metric(server.url, 'netapp_source_up{source="door"}') == 1
        assert metric(server.url, 'netapp_source_subscribers{source="door"}') == 1
        [page] = [r for r in requests.get(server.url + "/ui/api/robots", timeout=5).json()["robots"]]
        assert (page["robot_id"], page["transport"], page["frame_size"]) == ("door", "rtsp", "320x240")

        camera.stop()
        away = time.monotonic()
        wait_until(lambda: metric(server.url, 'netapp_source_up{source="door"}') == 0, 10, "the camera to be lost")
        # The outage itself, not a synchronisation: the camera stays away this long while the netapp retries.
        time.sleep(max(0.0, OUTAGE_S - (time.monotonic() - away)))
        quiet = watcher.since(away + 1.0)
        camera.start()
        back = time.monotonic()
        assert quiet == []  # nothing came while it was away (a picture in flight at the cut may)
        wait_until(lambda: watcher.since(back), RESUME_BOUND_S + 5, "results after the camera came back")
        resumed_s = watcher.since(back)[0][0] - back
        assert resumed_s <= RESUME_BOUND_S, f"results resumed {resumed_s:.1f} s after the camera was back"

    lines = [r.getMessage() for r in caplog.records if r.name == READER_LOG]
    assert [line for line in lines if ": lost (" in line] and len([ln for ln in lines if ": lost (" in ln]) == 1
    [back_line] = [line for line in lines if ": back after " in line]
    assert float(back_line.split("back after ")[1].split(" s")[0]) >= OUTAGE_S - 1
    assert len(lines) == 3, lines  # connected, lost, back: not a line per attempt
    assert metric(server.url, 'netapp_source_outages_total{source="door"}') == 1

    server.stop()
    assert camera_threads() == []
    assert sockets_to(camera.port) == []  # the RTSP connection
    assert udp_sockets() == udp_before  # and the RTP/RTCP sockets


def test_two_cameras_are_two_sessions_with_their_own_results_over_frames_and_socketio(cameras, serve, tiny_detector):
    # A camera each: a shared GStreamer media prepared for one viewer's transport can refuse the other's (5XX), and
    # which viewer comes first is a race, so one camera for both made this test fail now and then.
    left_camera, right_camera = cameras(), cameras()
    server = serve(tiny_detector, settings_for(f"left={left_camera.url}", f"right={right_camera.url}#transport=tcp"))
    right: list[dict] = []
    sio = socketio.Client(reconnection=False)
    sio.on("results", right.append, namespace=DATA_NAMESPACE)
    sio.connect(server.url, namespaces=[DATA_NAMESPACE, CONTROL_NAMESPACE], transports=["websocket"])
    try:
        ack = sio.call("command", {"cmd_type": CommandType.WATCH, "data": {"source": "right"}}, CONTROL_NAMESPACE, 10)
        assert ack[0] is True and ack[1].startswith("watching camera right (now ")
        with Watcher(server.url, "left") as left:
            wait_until(lambda: left.count() >= 5 and len(right) >= 5, 30, "both cameras' results")
    finally:
        sio.disconnect()
    assert {r["source"] for _, r in left.got} == {"left"} and {r["source"] for r in right} == {"right"}
    assert metric(server.url, 'netapp_active_sessions{transport="rtsp"}') == 2
    wait_until(lambda: metric(server.url, 'netapp_source_subscribers{source="right"}') == 0, 10, "the robot to leave")


def test_a_camera_whose_pictures_are_too_large_is_refused_before_it_costs_anything(
    cameras, serve, tiny_detector, caplog
):
    caplog.set_level(logging.WARNING, logger=READER_LOG)
    camera = cameras(width=320, height=240)
    server = serve(tiny_detector, settings_for(f"big={camera.url}", max_pixels=320 * 240 - 1))
    wait_until(
        lambda: any("too_many_pixels" in r.getMessage() or "pixels" in r.getMessage() for r in caplog.records), 20
    )
    [line] = [r.getMessage() for r in caplog.records if r.name == READER_LOG]
    assert "320x240 = 76800 pixels is over this netapp's limit of 76799" in line and "--max-pixels" in line
    assert metric(server.url, 'netapp_frames_received_total{transport="rtsp"}') == 0


def test_a_camera_unreachable_then_refused_for_its_size_is_told_again(camera_tools, serve, tiny_detector, caplog):
    caplog.set_level(logging.WARNING, logger=READER_LOG)
    port = free_port()
    serve(tiny_detector, settings_for(f"late=rtsp://127.0.0.1:{port}/cam", max_pixels=320 * 240 - 1))
    wait_until(lambda: any("late: unreachable" in r.getMessage() for r in caplog.records), 20, "the outage told")
    with RtspCamera(port, 320, 240):
        wait_until(lambda: any("late: refused" in r.getMessage() for r in caplog.records), 30, "the refusal told")
    refusals = [r.getMessage() for r in caplog.records if "late: refused" in r.getMessage()]
    assert len(refusals) == 1 and "320x240 = 76800 pixels is over" in refusals[0]  # once, however many retries


def test_watch_names_the_cameras_there_are_and_counts_its_subscribers(serve, tiny_detector, monkeypatch):
    monkeypatch.setattr(watchers, "MAX_PER_ADDRESS", MAX_PER_CAMERA + 1)  # the crowd all comes from loopback
    # No camera answers at this port: the netapp has the source, and keeps retrying it.
    server = serve(tiny_detector, settings_for(f"yard=rtsp://127.0.0.1:{free_port()}/cam"))
    with pytest.raises(NetAppRefused, match="no camera 'gate' here: this netapp pulls yard"):
        with Watcher(server.url, "gate") as watcher:
            wait_until(lambda: watcher.error, 10, "the refusal")
            raise watcher.error
    with Watcher(server.url, "yard"):
        wait_until(lambda: metric(server.url, 'netapp_source_subscribers{source="yard"}') == 1, 10, "the subscriber")
    wait_until(lambda: metric(server.url, 'netapp_source_subscribers{source="yard"}') == 0, 10, "it to leave")
    with contextlib.ExitStack() as stack:
        crowd = [stack.enter_context(Watcher(server.url, "yard")) for _ in range(MAX_PER_CAMERA)]
        wait_until(lambda: metric(server.url, 'netapp_source_subscribers{source="yard"}') == len(crowd), 10, "crowd")
        with Watcher(server.url, "yard") as late:
            wait_until(lambda: late.error, 10, "the refusal")
        assert late.error.reason == "too_many_subscribers" and late.error.retry_after_s == 5
    assert metric(server.url, 'netapp_source_up{source="yard"}') == 0
    assert metric(server.url, 'netapp_frames_rejected_total{reason="bad_command",transport="frames"}') == 2


def test_one_address_holds_a_few_watchers_and_a_watcher_that_reads_nothing_is_let_go(serve, tiny_detector):
    server = serve(tiny_detector, settings_for(f"yard=rtsp://127.0.0.1:{free_port()}/cam"))
    with contextlib.ExitStack() as stack:
        mine = [stack.enter_context(Watcher(server.url, "yard")) for _ in range(MAX_PER_ADDRESS)]
        wait_until(lambda: metric(server.url, 'netapp_source_subscribers{source="yard"}') == len(mine), 10, "mine")
        with Watcher(server.url, "yard") as late:
            wait_until(lambda: late.error, 10, "the refusal")
        assert late.error.reason == "too_many_watchers" and late.error.retry_after_s == 5
        assert "127.0.0.1 watches 4 cameras already" in str(late.error)
    assert metric(server.url, 'netapp_source_watchers_refused_total{reason="too_many_watchers"}') == 1


def test_a_netapp_without_cameras_refuses_watch(tiny_server):
    with Watcher(tiny_server.url, "door") as watcher:
        wait_until(lambda: watcher.error, 10, "the refusal")
    assert "pulls no camera" in str(watcher.error)


def test_a_camera_decoding_cannot_keep_up_with_drops_to_keyframes_once_and_says_so(
    cameras, serve, tiny_detector, caplog, monkeypatch
):
    from netapp.server.sources import keeping_up

    monkeypatch.setattr(keeping_up, "MAX_BEHIND_S", -1.0)  # every picture is "behind": as on a machine far too slow
    caplog.set_level(logging.WARNING, logger=READER_LOG)
    camera = cameras(fps=15)  # a keyframe a second
    server = serve(tiny_detector, settings_for(f"slow={camera.url}"))
    with Watcher(server.url, "slow") as watcher:
        wait_until(lambda: metric(server.url, 'netapp_source_keyframes_only{source="slow"}') == 1, 30, "keyframes only")
        start, decoded = time.monotonic(), metric(server.url, 'netapp_source_pictures_decoded_total{source="slow"}')
        wait_until(lambda: len(watcher.since(start)) >= 3, 20, "results from keyframes")
        rate = (metric(server.url, 'netapp_source_pictures_decoded_total{source="slow"}') - decoded) / (
            time.monotonic() - start
        )
    assert rate < 5  # a keyframe a second, not the camera's 15 pictures
    lines = [r.getMessage() for r in caplog.records if "cannot keep up" in r.getMessage()]
    assert len(lines) == 1 and "only its keyframes are decoded" in lines[0]


def test_netapp_watch_writes_a_cameras_results_as_json_lines_and_an_mcap(cameras, serve, tiny_detector, tmp_path):
    pytest.importorskip("mcap_ros2", reason="mcap-ros2-support is not installed: pip install 'netapp-toolkit[ros]'")
    from netapp.cli import main as netapp_main
    from netapp.ros.recorder import DETECTIONS_TOPIC, IMAGE_TOPIC
    from tests.support.bags import read_mcap

    camera = cameras()
    server = serve(tiny_detector, settings_for(f"door={camera.url}"))
    jsonl, mcap = tmp_path / "door.jsonl", tmp_path / "door.mcap"
    argv = ["watch", server.url, "--source", "door", "--count", "5", "--jsonl", str(jsonl), "--mcap", str(mcap)]
    assert netapp_main(argv) == 0
    records = [json.loads(line) for line in jsonl.read_text().splitlines()]
    assert len(records) == 5 and all(r["source"] == server.url and r["detections"] for r in records)
    assert all(r["source_stamp_ns"] == r["timestamp"] for r in records)  # when the netapp decoded the picture
    topics = read_mcap(mcap)
    detections = topics[DETECTIONS_TOPIC]
    assert len(detections) == 5 and IMAGE_TOPIC not in topics  # a subscriber gets results, not pictures
    assert [t for t, _ in detections] == [r["timestamp"] for r in records]
    assert netapp_main(["watch", server.url, "--source", "gate", "--count", "1"]) == 1  # no such camera: one line


def test_cameras_that_stall_or_talk_nonsense_are_told_once_and_leave_nothing_behind(
    camera_tools, serve, tiny_detector, caplog
):
    caplog.set_level(logging.INFO, logger=READER_LOG)
    silent, nonsense = HostileCamera(), HostileCamera(b"HTTP/1.0 200 OK\r\n\r\n" + b"\x00\xff" * 5000)
    try:
        sources = settings_for(f"silent=rtsp://127.0.0.1:{silent.port}/cam", f"junk=rtsp://127.0.0.1:{nonsense.port}/c")
        server = serve(tiny_detector, sources)

        def told(name: str) -> list[str]:
            return [r.getMessage() for r in caplog.records if r.getMessage().startswith(f"camera {name}: ")]

        # the silent one is given up on at the open timeout (5 s), not held forever
        wait_until(lambda: told("silent") and told("junk"), 20, "both cameras to be told unreachable")
        wait_until(lambda: len(silent.accepted) >= 2 and len(nonsense.accepted) >= 2, 30, "a retry of each")
        assert len(told("silent")) == 1 and len(told("junk")) == 1  # once per outage, whatever the retries
        assert "unreachable" in told("silent")[0] and "unreachable" in told("junk")[0]
        assert metric(server.url, 'netapp_frames_received_total{transport="rtsp"}') == 0
        server.stop()
        assert camera_threads() == []
        assert sockets_to(silent.port) == [] and sockets_to(nonsense.port) == []
    finally:
        silent.close()
        nonsense.close()


def test_a_camera_that_hangs_is_lost_at_the_read_timeout_in_words_not_a_slow_decoder(
    cameras, serve, tiny_detector, caplog
):
    """The camera's process stopped (as a frozen device or a cut cable): its connection stays open and nothing
    comes. That is a stall, not decoding falling behind: lost READ_TIMEOUT_S (2 s, docs/cameras.md) after its last
    picture, the reason in words, and nothing said about keyframes."""
    import signal

    from netapp.server.sources.reader import READ_TIMEOUT_S

    caplog.set_level(logging.INFO, logger=READER_LOG)
    camera = cameras(fps=15)
    server = serve(tiny_detector, settings_for(f"door={camera.url}"))
    with Watcher(server.url, "door") as watcher:
        wait_until(lambda: len(watcher.since(0)) >= 3, 30, "results from the camera")
        camera.process.send_signal(signal.SIGSTOP)
        try:
            hung_at = time.monotonic()
            lost = wait_until(
                lambda: [r for r in caplog.records if "door: lost" in r.getMessage()], 15, "the camera to be lost"
            )
            lost_after = time.monotonic() - hung_at
        finally:
            camera.process.send_signal(signal.SIGCONT)
    said = [r.getMessage() for r in caplog.records if r.getMessage().startswith("camera door")]
    assert not [line for line in said if "keep up" in line], said
    assert READ_TIMEOUT_S - 0.5 < lost_after < READ_TIMEOUT_S + 1.0, (lost_after, said)
    message = lost[0].getMessage()
    assert "Errno" not in message and "Immediate exit" not in message, message
    assert f"no data for {READ_TIMEOUT_S:g} s" in message, message
