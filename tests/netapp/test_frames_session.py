"""The robot's side of a `frames` connection, free of I/O (`netapp.frames_session`), the one reconnect policy
(`netapp.reconnect`), and that every frames client is only their I/O."""

from __future__ import annotations

import inspect
import json

import pytest

from netapp.client import watch
from netapp.client.link import NetAppLink
from netapp.client.transports import frames, rtp, socketio
from netapp.frame import EncodedFrame
from netapp.frames_session import (
    MAX_MESSAGE_BYTES,
    Acked,
    FrameError,
    FramesSession,
    Moved,
    Refused,
    Results,
    SessionInfo,
)
from netapp.framing import parse_frame
from netapp.protocol import CommandType
from netapp.reconnect import ReconnectPolicy
from netapp.server.sources import relay


def ack(ident, ok=True, **fields) -> str:
    return json.dumps({"event": "ack", "id": ident, "ok": ok, "message": "m", **fields})


def test_commands_are_numbered_and_each_ack_matched_once():
    session = FramesSession()
    init, state = session.command(CommandType.INIT, {"robot_id": "r"}), session.command(CommandType.SET_STATE, {})
    assert (init.ident, state.ident) == (1, 2)
    assert json.loads(init.text) == {"id": 1, "cmd_type": 1, "clear_queue": False, "data": {"robot_id": "r"}}
    got = session.receive(ack(2, session_id="s"))
    assert got == Acked(2, {"event": "ack", "id": 2, "ok": True, "message": "m", "session_id": "s"}) and got.ok
    assert session.receive(ack(2)) is None  # answered already: a second ack is stale
    for made_up in (1000, "1", None, [1], True):
        assert session.receive(ack(made_up)) is None
    session.abandon(1)  # timed out: its late ack is dropped
    assert session.receive(ack(1)) is None


def test_a_refused_command_is_an_ack_that_says_why():
    session = FramesSession()
    ident = session.command(CommandType.INIT, {}).ident
    got = session.receive(ack(ident, ok=False, reason="sessions_full", retry_after_s=3, limit=2))
    assert isinstance(got, Acked) and not got.ok and got.answer["reason"] == "sessions_full"
    assert session.refused is None  # the connection goes on


def test_a_refused_connection_and_a_move_are_typed_outcomes():
    session = FramesSession()
    body = {"error": "no token", "reason": "unauthorized"}
    assert session.receive(json.dumps({"event": "refused", "data": body})) == Refused(body)
    assert session.refused == body
    assert FramesSession().receive(json.dumps({"event": "refused", "data": "odd"})) == Refused({"error": "odd"})
    move = json.dumps({"event": "move", "data": {"reason": "draining", "message": "bye"}})
    assert session.receive(move) == Moved("draining")
    assert session.receive(json.dumps({"event": "move"})) == Moved("move")


def test_results_errors_and_session_info_are_read():
    session = FramesSession()
    assert session.receive(json.dumps({"event": "results", "data": {"timestamp": 1}})) == Results({"timestamp": 1})
    error = {"timestamp": 1, "error": "late", "reason": "deadline"}
    assert session.receive(json.dumps({"event": "error", "data": error})) == FrameError(error)
    info = {"input_size": [640, 480]}
    assert session.receive(json.dumps({"event": "session_info", "data": info})) == SessionInfo(info)
    junk = (b"\x00binary", "[1]", "not json", '{"event": 3}', '{"event": "results", "data": [1]}', '{"event": "x"}')
    for text in junk:
        assert session.receive(text) is None


def test_one_message_limit_for_every_client():
    session = FramesSession()
    assert session.socket_options()["max_size"] == MAX_MESSAGE_BYTES == 16 * 1024 * 1024
    big = json.dumps({"event": "results", "data": {"pad": "x" * 100}})
    assert FramesSession(max_message_bytes=len(big) - 1).receive(big) is None
    assert FramesSession(max_message_bytes=len(big)).receive(big) == Results({"pad": "x" * 100})


def test_frames_are_packed_and_unknown_codecs_refused():
    frame = EncodedFrame("jpeg", 7, b"\xff\xd8", deadline_ms=50.0, meta={"latency": {"uplink_ms": 1.0}})
    assert parse_frame(FramesSession().frame(frame)) == frame
    with pytest.raises(ValueError, match="vp8"):
        FramesSession().frame(EncodedFrame("vp8", 7, b""))


def schedule(policy: ReconnectPolicy, refusals: list[float | None]) -> list[float]:
    return [policy.next_s()] + [policy.next_s(r) for r in refusals]


def test_the_reconnect_policy_doubles_up_to_its_bound_and_takes_a_retry_after():
    assert schedule(ReconnectPolicy(0.5, 5.0), [None] * 6) == [0.5, 1.0, 2.0, 4.0, 5.0, 5.0, 5.0]
    assert schedule(ReconnectPolicy(0.5, 5.0), [None, 30.0, None]) == [0.5, 1.0, 30.0, 5.0]  # the netapp said when
    assert schedule(ReconnectPolicy(0.0, 2.0, floor_s=0.05), [None] * 6) == [0.0, 0.1, 0.2, 0.4, 0.8, 1.6, 2.0]
    assert schedule(ReconnectPolicy(0.0, 1.0, floor_s=0.5, retry_after_max_s=5.0), [None, 9.0, 2.0, None]) == [
        0.0,
        1.0,
        5.0,  # bounded
        2.0,
        1.0,
    ]
    policy = ReconnectPolicy(0.5, 5.0)
    schedule(policy, [None] * 3)
    policy.reset()
    assert policy.next_s() == 0.5


def test_every_frames_client_is_only_the_sessions_io():
    """The transport, RTP's control channel (the transport's own subclass), `netapp watch` and the replica relay
    each drive a FramesSession and keep no protocol of their own (command ids, event names, a message bound)."""
    assert issubclass(rtp.RtpTransport, frames.FramesTransport)
    for module in (frames, watch, relay):
        source = inspect.getsource(module)
        assert "FramesSession()" in source, module.__name__
        for own in ('"cmd_type"', "read_event", "ACK_EVENT", "REFUSED_EVENT", "max_size=", "json.dumps"):
            assert own not in source, f"{module.__name__} still has {own}"
    assert "ReconnectPolicy(" in inspect.getsource(relay.Relay.run)
    assert "policy.next_s" in inspect.getsource(watch.subscribe)


def test_one_layer_reconnects_the_robots_sessions():
    """The link, for every transport (a dropped connection, a netapp unreachable at connect(), a move): no
    transport reconnects by itself."""
    assert "ReconnectPolicy(" in inspect.getsource(NetAppLink.reconnect)
    assert "self.reconnect" in inspect.getsource(NetAppLink._on_lost)
    assert not hasattr(frames.FramesTransport, "_reconnect")
    assert "reconnection=False" in inspect.getsource(socketio.SocketIOTransport.__init__)
