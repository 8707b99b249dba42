"""The `frames` transport on its own: a link that stops taking bytes never holds up the robot's thread, nor its
closing."""

from __future__ import annotations

import json
import threading

from websockets.sync.server import ServerConnection, serve

from netapp.client.transports import SessionSettings, TransportCallbacks
from netapp.client.transports.frames import FramesTransport
from netapp.frame import EncodedFrame

FRAME = b"\xff\xd8\xff" + bytes(1_000_000)  # 40 of them are far more than the socket buffers on both sides hold


def callbacks() -> TransportCallbacks:
    ignore = lambda *args: None  # noqa: E731
    return TransportCallbacks(ignore, ignore, ignore, ignore, ignore, ignore, ignore)


def test_transmit_never_waits_on_a_link_that_stops_reading():
    release = threading.Event()

    def netapp(ws: ServerConnection) -> None:  # acknowledges INIT, then reads nothing more
        ident = json.loads(ws.recv())["id"]
        ws.send(json.dumps({"event": "ack", "id": ident, "ok": True, "message": "initialized", "session_id": "s"}))
        release.wait(60)

    with serve(netapp, "127.0.0.1", 0, max_size=None, max_queue=1, close_timeout=0.5) as server:
        threading.Thread(target=server.serve_forever, daemon=True).start()
        url = f"http://127.0.0.1:{server.socket.getsockname()[1]}"
        transport = FramesTransport(url, SessionSettings(connect_timeout_s=5), callbacks())
        transport.connect()
        assert transport.session_id == "s"
        frames = [EncodedFrame("jpeg", i, FRAME) for i in range(40)]
        sending = threading.Thread(target=lambda: [transport.transmit(frame) for frame in frames], daemon=True)
        sending.start()
        sending.join(30)  # a deadline, not a measurement: without the writer thread it never ends
        try:
            assert not sending.is_alive(), "transmit waited on a link that stopped reading"
            closing = threading.Thread(target=transport.close, daemon=True)
            closing.start()
            closing.join(10)  # a frame is stuck on the link: closing cuts it off rather than wait for it
            assert not closing.is_alive(), "close() waited for a link that takes nothing"
        finally:
            release.set()
            server.shutdown()


def test_only_the_acknowledgements_a_command_waits_for_are_kept():
    """A netapp's acks of no command (made up, or a timed-out command's) are not kept: they would pile up."""

    def netapp(ws: ServerConnection) -> None:
        ident = json.loads(ws.recv())["id"]
        for made_up in (ident + 1000, [ident], "x", None):
            ws.send(json.dumps({"event": "ack", "id": made_up, "ok": True, "message": "?"}))
        ws.send(json.dumps({"event": "ack", "id": ident, "ok": True, "message": "initialized", "session_id": "s"}))
        ws.recv()  # until the robot closes

    with serve(netapp, "127.0.0.1", 0, close_timeout=0.5) as server:
        threading.Thread(target=server.serve_forever, daemon=True).start()
        url = f"http://127.0.0.1:{server.socket.getsockname()[1]}"
        transport = FramesTransport(url, SessionSettings(connect_timeout_s=5), callbacks())
        transport.connect()
        try:
            assert transport.session_id == "s"
            assert transport._answers == {} and transport._protocol._waiting == set()
        finally:
            transport.close()
