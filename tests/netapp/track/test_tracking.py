"""The tracking netapp end to end, with the real model on the pedestrian video: a netapp is killed mid-stream,
the robot moves to another one, and the tracks alive before the move keep their ids after it (matched by
position against a run without a move); for NetAppClient's checkpoints and for an unmodified era-5g-client robot
using GET_STATE / SET_STATE."""

from __future__ import annotations

import itertools
import json
import threading

import cv2
import numpy as np
import pytest

from netapp.client import NetAppClient
from netapp.serve_process import NetAppProcess
from netapp.track.compare import matched_ids
from tests.support.raw_robot import RawRobot

FRAMES = 48  # about two seconds of video: enough for tracks to be confirmed and to live through the move
MOVE_AT = 24
FRAME_NS = 40_000_000  # 25 fps: the frames' timestamps are their capture times


@pytest.fixture(scope="module")
def frames(media_dir) -> list[np.ndarray]:
    capture = cv2.VideoCapture(str(media_dir / "pedestrians.avi"))
    out = []
    while len(out) < FRAMES:
        ok, frame = capture.read()
        if not ok:
            break
        out.append(cv2.resize(frame, (640, 360)))
    capture.release()
    assert len(out) == FRAMES, "pedestrians.avi is shorter than the test needs"
    return out


@pytest.fixture(scope="module")
def jpegs(frames) -> list[bytes]:
    """The frames as every robot here sends them: cv2's default JPEG, which is what era-5g-client sends."""
    return [cv2.imencode(".jpg", frame)[1].tobytes() for frame in frames]


@pytest.fixture(scope="module")
def netapps(real_model_path):
    """start(): a tracking netapp in a process of its own; all are killed at the end."""
    started: list[NetAppProcess] = []

    def start(count: int = 1) -> list[NetAppProcess]:
        new = [
            NetAppProcess("--model", str(real_model_path), "--processor", "object-tracking").start()
            for _ in range(count)
        ]
        started.extend(new)
        return [n.wait_ready() for n in new]

    yield start
    for n in started:
        n.kill()


def lockstep(send, results, jpegs: list[bytes], first: int, last: int) -> list[list[dict]]:
    """Send frames first..last-1 one at a time, each after the previous one's result: every frame is tracked, so
    two runs over the same frames can be compared detection by detection."""
    out = []
    for i in range(first, last):
        timestamp = (i + 1) * FRAME_NS
        send(jpegs[i], timestamp)
        result = results(timestamp)
        out.append(result["detections"])
    return out


def raw_run(url: str, jpegs: list[bytes]) -> list[list[dict]]:
    robot = RawRobot(url)
    try:
        assert robot.init()[0]

        def results(timestamp):
            result = robot.next("results", timeout=30)
            assert result["timestamp"] == timestamp
            return result

        return lockstep(lambda jpeg, ts: robot.frame({"timestamp": ts, "frame": jpeg}), results, jpegs, 0, len(jpegs))
    finally:
        robot.close()


@pytest.fixture(scope="module")
def reference_netapp(netapps) -> NetAppProcess:
    (netapp,) = netapps()
    return netapp


@pytest.fixture(scope="module")
def reference(reference_netapp, jpegs) -> list[list[dict]]:
    """The run without a move."""
    return raw_run(reference_netapp.url, jpegs)


def client_run(client: NetAppClient, jpegs: list[bytes], first: int, last: int) -> list[list[dict]]:
    def results(timestamp):
        (result,) = list(itertools.islice(client.results(timeout=30), 1))
        assert result.timestamp == timestamp
        return result.message

    return lockstep(lambda jpeg, ts: client.send(jpeg, timestamp=ts), results, jpegs, first, last)


def assert_ids_continue(run: list[list[dict]], reference: list[list[dict]]) -> None:
    """The tracks alive before the move have, after it, the ids they had before (which are the reference's)."""
    assert len(run) == len(reference) == FRAMES
    alive = {d["track_id"] for d in run[MOVE_AT - 1] if d["track_id"] is not None}
    before = [pair for i in range(MOVE_AT) for pair in matched_ids(run[i], reference[i])]
    assert len(alive) >= 5 and all(a == b for a, b in before), "the runs differ before the move"
    after = [pair for i in range(MOVE_AT, FRAMES) for pair in matched_ids(run[i], reference[i])]
    kept = [(a, b) for a, b in after if b in alive]
    assert len({b for _, b in kept}) >= len(alive) // 2, "too few tracks alive before the move were seen after it"
    assert [a for a, _ in kept] == [b for _, b in kept], "a track alive before the move changed its id"
    assert all(a == b for a, b in after)  # and new tracks get the ids they got without a move


@pytest.mark.parametrize("transport", ["ws", "frames"])
def test_netapp_client_restores_its_checkpoint_after_a_failover(netapps, jpegs, reference, transport):
    first, second = netapps(2)
    with NetAppClient(first.url, transport=transport, checkpoint_every=1, max_in_flight=1) as client:
        run = client_run(client, jpegs, 0, MOVE_AT)
        first.kill()  # mid-stream, as a failed node: the robot is told to use another netapp (here by the test)
        client.switch_url(second.url)
        assert client.stats.restores == 1
        run += client_run(client, jpegs, MOVE_AT, FRAMES)
    assert_ids_continue(run, reference)


def test_without_the_state_a_move_restarts_the_ids(netapps, reference_netapp, jpegs, reference):
    """The control: what the two tests around it would see if the state did not move."""
    (first,) = netapps()
    with NetAppClient(first.url, transport="ws", max_in_flight=1) as client:
        run = client_run(client, jpegs, 0, MOVE_AT)
        client.switch_url(reference_netapp.url)
        run += client_run(client, jpegs, MOVE_AT, FRAMES)
    with pytest.raises(AssertionError, match="changed its id"):
        assert_ids_continue(run, reference)


def test_an_era_5g_client_robot_moves_its_tracks_with_get_and_set_state(netapps, frames, jpegs, reference):
    era = pytest.importorskip("era_5g_client.client_base", reason="era-5g-client is not installed (make install)")
    from era_5g_interface.channels import CallbackInfoClient, ChannelType
    from era_5g_interface.dataclasses.control_command import ControlCmdType, ControlCommand

    first, second = netapps(2)
    got: dict[int, dict] = {}
    arrived = threading.Condition()

    def on_result(message):
        with arrived:
            got[message["timestamp"]] = message
            arrived.notify_all()

    def results(timestamp):
        with arrived:
            assert arrived.wait_for(lambda: timestamp in got, timeout=30), "no result within 30 s"
            return got[timestamp]

    def robot(url):
        client = era.NetAppClientBase({"results": CallbackInfoClient(ChannelType.JSON, on_result)})
        client.register(url, args={})
        assert client.initialized
        return client

    def sender(client):
        def send(jpeg, timestamp):
            client.send_image(frames[timestamp // FRAME_NS - 1], "image", ChannelType.JPEG, timestamp)

        return send

    clients = [robot(first.url)]
    try:
        run = lockstep(sender(clients[0]), results, jpegs, 0, MOVE_AT)
        ok, state = clients[0].send_control_command(ControlCommand(ControlCmdType.GET_STATE))
        assert ok and json.loads(state)["tracks"]
        first.kill()
        clients.append(robot(second.url))
        ok, message = clients[1].send_control_command(ControlCommand(ControlCmdType.SET_STATE, data=json.loads(state)))
        assert ok, message
        run += lockstep(sender(clients[1]), results, jpegs, MOVE_AT, FRAMES)
    finally:
        for client in clients:
            threading.Thread(target=client.disconnect, daemon=True).start()  # see test_socketio: upstream race
    assert_ids_continue(run, reference)
