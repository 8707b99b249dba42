"""One connection type for every transport and camera, closed in one place; one command dispatch for INIT (with or
without RTP), WATCH, the state commands and HTTP's /register; one error event; transports over DataPlane's own
methods only."""

from __future__ import annotations

import ast
import asyncio
import re
from pathlib import Path
from typing import Any

import pytest
import requests

from netapp.frame import EncodedFrame
from netapp.protocol import CommandType, error_event
from netapp.server.commands import Commands
from netapp.server.connection import Connection
from netapp.server.dataplane import DataPlane
from netapp.server.errors import FrameRejected, RequestRefused
from netapp.server.frames.connection import FramesWire
from netapp.server.rtp.hub import PollingSink
from netapp.server.services import NetAppServices
from netapp.server.sessions import TOKEN_TRANSPORT
from netapp.server.settings import Settings
from netapp.server.sources.hub import Camera, Sources
from netapp.server.sources.naming import parse_source
from tests.netapp.server.test_state import FrameCounter
from tests.support.polling import wait_until
from tests.support.raw_frames_robot import RawFramesRobot
from tests.support.raw_robot import RawRobot

SERVER = Path(__file__).resolve().parents[3] / "netapp" / "server"
TRANSPORTS = ("sio", "frames", "http", "rtp", "webrtc", "sources")


class Decoder:
    """A FrameDecoder that records what was done to it."""

    in_order = False

    def __init__(self) -> None:
        self.resets = self.closes = 0

    def frame(self, frame: EncodedFrame) -> Any:
        return lambda: frame

    def reset(self) -> None:
        self.resets += 1

    def close(self) -> None:
        self.closes += 1


class FakeRtp:
    """RtpSessions as the dispatch sees it: `check` before the session opens, `open` with the connection after."""

    def __init__(self, refuse_open: bool = False) -> None:
        self.refuse_open = refuse_open
        self.opened: list[Connection] = []
        self.released: list[str] = []

    def check(self, value: Any) -> Any:
        if value == "bad":
            raise RequestRefused("bad_rtp", "not an RTP request", 422)
        return value

    async def open(self, connection: Connection, request: Any) -> dict[str, Any]:
        if self.refuse_open:
            raise RequestRefused("rtp_ports_full", "every port is held", 503, retry_after_s=5)
        self.opened.append(connection)
        session_id = connection.session.id
        connection.hold(lambda: self.released.append(session_id))
        return {"port": 50000, "ssrc": 1, "sdp": "m=video"}


def dataplane(**settings: Any) -> DataPlane:
    return DataPlane(NetAppServices.build(FrameCounter(), Settings(**settings)))


# -- the connection and its one close ----------------------------------------------------------------------------------


def test_closing_a_connection_releases_everything_it_holds_once():
    plane = dataplane()
    connection = plane.connect(Connection("robot-1", "frames", outlives_session=True))
    decoder = connection.decoder("h264", Decoder)
    assert connection.decoder("h264", Decoder) is decoder  # one per connection and codec
    released: list[str] = []
    plane.open_session("frames", "r1", {}, session_id="robot-1", connection=connection)
    connection.hold(lambda: released.append("port"))
    connection.on_close(lambda: released.append("subscription"))

    plane.close_session(connection.session, "idle")  # the session ends first: its holds go, the wire stays
    assert released == ["port"] and decoder.closes == 0 and plane.connection("robot-1") is connection

    plane.disconnect(connection, "the robot disconnected")  # then the wire: the rest goes, once
    plane.disconnect(connection, "the robot disconnected")
    assert released == ["port", "subscription"] and decoder.closes == 1 and connection.closed
    assert plane.connection("robot-1") is None


def test_a_connection_that_ends_with_its_session_is_closed_by_the_session_and_a_failing_release_stops_none():
    plane = dataplane()
    connection = Connection("", "webrtc")
    session = plane.open_session("webrtc", "r1", {}, connection=connection)
    assert connection.key == session.id and plane.connection(session.id) is connection
    released: list[str] = []
    connection.hold(lambda: 1 / 0)  # a release that fails: the next ones run anyway
    connection.hold(lambda: released.append("peer"))
    plane.close_session(session, "the peer went")
    assert released == ["peer"] and connection.closed and plane.connection(session.id) is None
    assert plane.session(session.id) is None


# -- the one command dispatch ------------------------------------------------------------------------------------------


def test_init_with_rtp_and_register_with_rtp_open_the_same_way():
    async def main() -> None:
        plane = dataplane()
        rtp = FakeRtp()
        commands = Commands(plane, None, rtp)  # type: ignore[arg-type]
        robot = plane.connect(Connection("sid-1", "ws", outlives_session=True))
        init = {"cmd_type": CommandType.INIT, "data": {"robot_id": "r1", "rtp": {"payload_type": 96}}}
        answer = await commands.execute(robot, init)
        assert answer.ok and answer.rtp == {"port": 50000, "ssrc": 1, "sdp": "m=video"}
        assert answer.message == "initialized; send H.264 over RTP to port 50000" and answer.session_info is not None

        registered = await commands.register("r2", {"rtp": {"payload_type": 96}}, 0, "10.0.0.1")
        assert registered.rtp == answer.rtp
        http = plane.connection(registered.session.id)
        assert rtp.opened == [robot, http]  # the same opening, each with its own connection
        assert http.transport == TOKEN_TRANSPORT and isinstance(http.sink, PollingSink) and http.host == "10.0.0.1"
        plane.close_session(registered.session, "the session was unregistered", revoke=True)
        plane.disconnect(robot, "the robot disconnected")
        assert sorted(rtp.released) == sorted([registered.session.id, "sid-1"])  # each port went back with it

    asyncio.run(main())


def test_a_refused_rtp_refuses_init_and_register_alike_and_leaves_no_session():
    async def main() -> None:
        plane = dataplane()
        commands = Commands(plane, None, FakeRtp(refuse_open=True))  # type: ignore[arg-type]
        robot = plane.connect(Connection("sid-1", "ws", outlives_session=True))
        answer = await commands.execute(robot, {"cmd_type": CommandType.INIT, "data": {"rtp": {}}})
        assert not answer.ok and answer.refused == {"reason": "rtp_ports_full", "retry_after_s": 5}
        assert robot.live_session is None and plane.session("sid-1") is None
        with pytest.raises(RequestRefused, match="every port is held"):
            await commands.register("r2", {"rtp": {}}, 0, "127.0.0.1")
        checked = await commands.execute(robot, {"cmd_type": CommandType.INIT, "data": {"rtp": "bad"}})
        assert not checked.ok and checked.refused["reason"] == "bad_rtp"
        with pytest.raises(RequestRefused, match="not an RTP request"):
            await commands.register("r2", {"rtp": "bad"}, 0, "127.0.0.1")
        assert list(plane.connections(TOKEN_TRANSPORT)) == []

    asyncio.run(main())


def test_reset_state_resets_the_connections_decoders_and_watch_is_released_with_it():
    async def main() -> None:
        plane = dataplane(sources=(parse_source("cam=rtsp://127.0.0.1:1/x"),))
        sources = Sources(plane, plane.settings)
        told: list[dict] = []
        sources.cameras["cam"] = Camera(parse_source("cam=rtsp://127.0.0.1:1/x"), session=None)  # type: ignore[arg-type]
        commands = Commands(plane, sources)
        robot = plane.connect(Connection("sid-1", "frames", tell=told.append, outlives_session=True))
        decoder = robot.decoder("h264", Decoder)
        watch = await commands.execute(robot, {"cmd_type": CommandType.WATCH, "data": {"source": "cam"}})
        assert watch.ok and list(sources.cameras["cam"].subscribers) == [told.append]
        assert (await commands.execute(robot, {"cmd_type": CommandType.INIT, "data": {}})).ok
        assert (await commands.execute(robot, {"cmd_type": CommandType.RESET_STATE})).ok and decoder.resets == 1
        plane.disconnect(robot, "the robot disconnected")
        assert not sources.cameras["cam"].subscribers and decoder.closes == 1

    asyncio.run(main())


def test_a_camera_is_one_connection_closed_with_the_netapp(monkeypatch):
    for name in ("KUBECONFIG", "KUBERNETES_SERVICE_HOST"):
        monkeypatch.delenv(name, raising=False)

    async def main() -> None:
        # --camera-leases without a cluster: the camera's session opens, nothing is pulled
        plane = dataplane(sources=(parse_source("cam=rtsp://127.0.0.1:1/x"),), camera_leases="default")
        sources = Sources(plane, plane.settings)
        await sources.start()
        connection = plane.connection("camera:cam")
        assert isinstance(connection, Connection) and isinstance(connection.wire, Camera)
        assert sources.camera_of("camera:cam") is connection.wire and connection.session.transport == "rtsp"
        await sources.stop()
        assert connection.closed and plane.connection("camera:cam") is None

    asyncio.run(main())


# -- every transport on a server ---------------------------------------------------------------------------------------


def test_every_robot_transport_keeps_one_connection_type(tiny_server):
    plane = tiny_server.app.other_asgi_app.state.dataplane
    sio, frames = RawRobot(tiny_server.url), RawFramesRobot(tiny_server.url)
    try:
        assert sio.init()[0] and frames.init()["ok"]
        (on_sio,) = plane.connections("ws")
        (on_frames,) = plane.connections("frames")
        assert on_sio.key == sio.sio.eio.sid and on_sio.wire == sio.sio.namespaces["/data"]  # its /data sid
        assert isinstance(on_frames.wire, FramesWire) and on_frames.live_session is not None
        registered = requests.post(f"{tiny_server.url}/register", json={"robot_id": "h"}, timeout=10).json()
        on_http = plane.connection(registered["session_id"])
        assert isinstance(on_http, Connection) and on_http.transport == TOKEN_TRANSPORT
        requests.post(f"{tiny_server.url}/unregister", headers={"X-Session-Id": on_http.key}, timeout=10)
        assert on_http.closed and plane.connection(on_http.key) is None
    finally:
        sio.close()
        frames.close()
    wait_until(lambda: on_sio.closed and on_frames.closed, what="both connections closed")
    assert plane.connections("ws") == plane.connections("frames") == []
    assert on_sio.session.closed and on_frames.session.closed


def test_the_error_event_is_the_same_on_every_transport(tiny_server):
    sio, frames = RawRobot(tiny_server.url), RawFramesRobot(tiny_server.url)
    try:
        sio.init()
        frames.init()
        sio.frame({"timestamp": 5, "frame": b"\xff\xd8\xffjunk"})
        frames.frame(5, b"\xff\xd8\xffjunk")
        on_sio, on_frames = sio.next("data_error"), frames.next("error")
    finally:
        sio.close()
        frames.close()
    assert on_sio == on_frames and on_sio.keys() == {"timestamp", "error", "reason"} and on_sio["reason"] == "bad_frame"
    assert FrameRejected("bad_frame", "x").event(5) == error_event(5, "x", "bad_frame")


# -- what the transports' code may touch -------------------------------------------------------------------------------


def transport_sources() -> list[Path]:
    files = [p for name in TRANSPORTS for p in (SERVER / name).rglob("*.py")]
    return [p for p in files if p.name != "relay.py"]  # the replica relay is a frames client (not the netapp's side)


def test_transports_use_the_dataplanes_methods_never_its_internals():
    internals = re.compile(r"(data)?plane\.(services|pipeline|settings)\b|\.services\.")
    found = [f"{p}:{n}" for p in transport_sources() for n, line in enumerate(p.read_text().splitlines(), 1)
             if internals.search(line)]  # fmt: skip
    assert found == []


def dicts_with(paths: list[Path], keys: set[str]) -> list[str]:
    """Where a dict literal with all of `keys` is written out."""
    found = []
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Dict) and keys <= {k.value for k in node.keys if isinstance(k, ast.Constant)}:
                found.append(f"{path}:{node.lineno}")
    return found


def test_no_transport_writes_out_an_error_event_or_a_5g_era_frame_dict():
    """The error event comes from `netapp.protocol.error_event`; decoders take an EncodedFrame, so no edge builds the
    5G-ERA dict for them."""
    assert dicts_with(list(SERVER.rglob("*.py")), {"timestamp", "error", "reason"}) == []
    edges = transport_sources() + list((SERVER / "decoding").rglob("*.py"))
    assert dicts_with(edges, {"timestamp", "frame"}) == []
