"""Session state over the wire: a stateful SDK processor, the 5G-ERA state commands on /control, checkpoints in
results, SAVE_STATE / LOAD_STATE in a directory, and bad states refused with nothing changed."""

from __future__ import annotations

import json
import threading
import time

import pytest
import requests

from netapp.sdk.processor import StatefulProcessor
from netapp.server.settings import Settings
from tests.support.images import make_jpeg
from tests.support.raw_robot import RawRobot


class FrameCounter(StatefulProcessor):
    """Counts each session's frames: the smallest processor whose results depend on its state."""

    name = "frame-counter"
    max_batch = 4

    def __init__(self) -> None:
        self.batches: list[int] = []

    def prepare(self, image, args):
        return image.shape

    def process(self, batch):
        self.batches.append(len(batch))
        return [{"shape": list(shape)} for shape in batch]

    def new_state(self, args):
        return {"count": int(args.get("start", 0))}

    def update(self, state, result, timestamp):
        state["count"] += 1
        return {**result, "count": state["count"]}

    def state_from_json(self, data):
        if not isinstance(data, dict) or not isinstance(data.get("count"), int):
            raise ValueError("expected {'count': int}")
        return {"count": data["count"]}


@pytest.fixture
def counter_robot(serve, tmp_path):
    server = serve(FrameCounter(), Settings(state_dir=str(tmp_path / "states")))
    robots = []

    def connect(**init):
        robot = RawRobot(server.url)
        robots.append(robot)
        assert list(robot.init(**init)) == [True, "initialized"]
        return robot

    connect.server = server
    yield connect
    for robot in robots:
        robot.close()


def send(robot: RawRobot, timestamp: int) -> dict:
    robot.frame({"timestamp": timestamp, "frame": make_jpeg()})
    result = robot.next("results")
    assert result["timestamp"] == timestamp
    return result


def command(robot: RawRobot, cmd_type: int, data=None) -> list:
    return list(robot.command({"cmd_type": cmd_type, "clear_queue": False, "data": data or {}}))


def test_state_commands_get_set_reset(counter_robot):
    robot = counter_robot(start=10)
    assert [send(robot, t)["count"] for t in (1, 2)] == [11, 12]
    assert command(robot, 3) == [True, json.dumps({"count": 12}, separators=(",", ":"))]  # GET_STATE
    assert command(robot, 4, {"count": 100}) == [True, "state set"]  # SET_STATE: `data` is the state
    assert send(robot, 3)["count"] == 101
    assert command(robot, 2) == [True, "state reset"]  # RESET_STATE: a fresh state from INIT's arguments
    assert send(robot, 4)["count"] == 11
    other = counter_robot()
    assert send(other, 1)["count"] == 1  # each session its own state


@pytest.mark.parametrize(
    "data, message",
    [
        ({"count": "many"}, "cannot restore this state: expected {'count': int}"),
        ({"count": 1, "pad": "x" * 300_000}, "over the 262144-byte limit"),
    ],
)
def test_a_bad_state_is_refused_with_a_clear_message_and_changes_nothing(counter_robot, data, message):
    robot = counter_robot()
    send(robot, 1)
    ok, ack = command(robot, 4, data)
    assert not ok and message in ack
    assert message in robot.next("command_error")["error"]
    assert send(robot, 2)["count"] == 2


def test_checkpoints_every_n_results(counter_robot):
    robot = counter_robot(state_checkpoint_every=2)
    results = [send(robot, t) for t in range(1, 6)]
    assert [r.get("state") for r in results] == [None, {"count": 2}, None, {"count": 4}, None]


@pytest.mark.parametrize("every", [-1, "2", 10_001, True])
def test_a_bad_checkpoint_request_refuses_init(counter_robot, every):
    robot = RawRobot(counter_robot.server.url)
    try:
        ok, message = robot.init(state_checkpoint_every=every)
        assert not ok and "'state_checkpoint_every' must be an integer" in message
    finally:
        robot.close()


def test_save_and_load_state_in_the_state_dir(counter_robot, tmp_path):
    first = counter_robot(robot_id="r1")
    send(first, 1)
    assert command(first, 5) == [True, "state saved as 'r1'"]  # SAVE_STATE, named after the robot
    assert json.loads((tmp_path / "states" / "r1.json").read_text()) == {"count": 1}
    assert command(first, 5, {"name": "checkpoint-2"})[0]
    second = counter_robot()
    assert command(second, 6, {"name": "r1"}) == [True, "state 'r1' loaded"]  # LOAD_STATE
    assert send(second, 1)["count"] == 2
    assert command(second, 6, {"name": "nobody"}) == [False, "no saved state named 'nobody'; SAVE_STATE it first"]
    ok, message = command(second, 5, {"name": "../escape"})
    assert not ok and "not starting with a dot" in message
    ok, message = command(second, 5)
    assert not ok and "needs data {'name': ...}" in message
    assert sorted(p.name for p in (tmp_path / "states").iterdir()) == ["checkpoint-2.json", "r1.json"]


def test_without_a_state_dir_save_is_refused(serve):
    server = serve(FrameCounter())
    robot = RawRobot(server.url)
    try:
        robot.init()
        ok, message = command(robot, 5, {"name": "x"})
        assert not ok and "start it with --state-dir DIR" in message
    finally:
        robot.close()


def test_stateless_processors_refuse_state_commands_but_get_state_tells_counters(robot_on_detector):
    robot = robot_on_detector
    ok, message = command(robot, 4, {"count": 1})
    assert not ok and "needs a stateful processor" in message
    ok, message = command(robot, 3)
    assert ok and json.loads(message)["transport"] == "ws"


@pytest.fixture
def robot_on_detector(tiny_server):
    robot = RawRobot(tiny_server.url)
    robot.init()
    yield robot
    robot.close()


def test_one_batch_across_robots_updates_each_sessions_own_state(serve):
    class Gated(FrameCounter):
        """Holds the first batch until the test has queued frames from the other robots."""

        def __init__(self) -> None:
            super().__init__()
            self.entered, self.gate = threading.Event(), threading.Event()

        def process(self, batch):
            if not self.batches:
                self.entered.set()
                assert self.gate.wait(30)
            return super().process(batch)

    processor = Gated()
    server = serve(processor)
    robots = [RawRobot(server.url) for _ in range(3)]
    try:
        for i, r in enumerate(robots):
            r.init(start=100 * i)
        robots[0].frame({"timestamp": 1, "frame": make_jpeg()})
        assert processor.entered.wait(10)
        for r in robots[1:]:
            r.frame({"timestamp": 1, "frame": make_jpeg()})
        deadline = time.monotonic() + 10
        while "netapp_queue_depth 2.0" not in requests.get(f"{server.url}/metrics", timeout=5).text:
            assert time.monotonic() < deadline, "the other robots' frames were never queued"
            time.sleep(0.02)  # polling a metric with a deadline
        processor.gate.set()
        assert [r.next("results")["count"] for r in robots] == [1, 101, 201]
        assert processor.batches == [1, 2]  # robots 1 and 2 shared a batch, each with its own state
        for r in robots:
            r.frame({"timestamp": 2, "frame": make_jpeg()})
        assert [r.next("results")["count"] for r in robots] == [2, 102, 202]
    finally:
        processor.gate.set()
        for r in robots:
            r.close()


def test_http_sessions_get_checkpoints_too(serve):
    server = serve(FrameCounter())
    sid = requests.post(f"{server.url}/register", json={"args": {"state_checkpoint_every": 1}}, timeout=5).json()
    headers = {"X-Session-Id": sid["session_id"], "Content-Type": "image/jpeg", "X-Timestamp": "5"}
    result = requests.post(f"{server.url}/send_image?wait=true", data=make_jpeg(), headers=headers, timeout=10).json()
    assert result["count"] == 1 and result["state"] == {"count": 1}
    bad = requests.post(f"{server.url}/register", json={"args": {"state_checkpoint_every": -1}}, timeout=5)
    assert bad.status_code == 422 and "state_checkpoint_every" in bad.json()["error"]


@pytest.mark.parametrize("transport", ["ws", "http", "frames"])
def test_the_client_keeps_the_latest_checkpoint_and_restores_it_on_a_new_netapp(serve, transport):
    from netapp.client import NetAppClient

    first, second = serve(FrameCounter()), serve(FrameCounter())
    with NetAppClient(first.url, transport=transport, checkpoint_every=2, max_in_flight=1) as client:
        for t in range(1, 6):
            client.send(make_jpeg(), timestamp=t)
            assert client.wait_idle(10)
        assert client.state == {"count": 4} and client.stats.checkpoints == 2
        assert [r.message["count"] for r in client.results(timeout=0.5)] == [1, 2, 3, 4, 5]
        client.switch_url(second.url)
        assert client.stats.restores == 1
        client.send(make_jpeg(), timestamp=6)
        assert client.wait_idle(10)
        (result,) = list(client.results(timeout=0.5))
        assert result.message["count"] == 5 and "state" not in result.message  # from the checkpoint at 4


def test_http_state_routes(serve, tiny_server):
    server = serve(FrameCounter())
    sid = requests.post(f"{server.url}/register", json={}, timeout=5).json()["session_id"]
    headers = {"X-Session-Id": sid}
    assert requests.put(f"{server.url}/state", json={"count": 41}, headers=headers, timeout=5).status_code == 204
    assert requests.get(f"{server.url}/state", headers=headers, timeout=5).json() == {"count": 41}
    bad = requests.put(f"{server.url}/state", json={"count": "x"}, headers=headers, timeout=5)
    assert bad.status_code == 422 and "expected {'count': int}" in bad.json()["error"]
    huge = requests.put(f"{server.url}/state", data=b"1" * 300_000, headers=headers, timeout=5)
    assert huge.status_code == 413 and "over the 262144-byte limit" in huge.json()["error"]
    other = requests.post(f"{tiny_server.url}/register", json={}, timeout=5).json()["session_id"]
    stateless = requests.get(f"{tiny_server.url}/state", headers={"X-Session-Id": other}, timeout=5)
    assert stateless.status_code == 409 and "keeps no session state" in stateless.json()["error"]


def test_a_state_dir_that_cannot_be_written_is_a_clear_refusal(serve, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    server = serve(FrameCounter(), Settings(state_dir=str(blocker / "states")))
    robot = RawRobot(server.url)
    try:
        robot.init()
        ok, message = command(robot, 5, {"name": "x"})
        assert not ok and "SAVE_STATE failed on the netapp's state volume" in message
        assert send(robot, 1)["count"] == 1  # the session carries on
    finally:
        robot.close()
