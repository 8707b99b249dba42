"""A bare `frames` robot (websockets' sync client) for checks of the wire format itself (`netapp.framing`)."""

from __future__ import annotations

import json
import queue
import threading
import time
from typing import Any

from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from netapp.client.transports.frames import frames_url
from netapp.frame import EncodedFrame
from netapp.framing import pack_frame
from tests.support.images import make_jpeg


class RawFramesRobot:
    """Sends what a test gives it, raw; records every event the netapp sends, and how the connection closed."""

    def __init__(self, url: str, headers: dict[str, str] | None = None, query: str = "") -> None:
        self.events: queue.Queue = queue.Queue()
        self.ws = connect(frames_url(url) + query, additional_headers=headers, max_size=None, open_timeout=10)
        self.close_code: int | None = None
        self.close_reason = ""
        self.closed = threading.Event()
        self.order: list[str] = []  # every event's name, in the order they came
        self._ids = iter(range(1, 1_000_000))
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        try:
            for text in self.ws:
                message = json.loads(text)
                self.order.append(message["event"])
                self.events.put(message)
        except ConnectionClosed:
            pass
        self.close_code, self.close_reason = self.ws.close_code, self.ws.close_reason or ""
        self.closed.set()

    def send(self, data: bytes | str) -> None:
        self.ws.send(data)

    def command(self, cmd_type: int, data: Any = None) -> dict[str, Any]:
        ident = next(self._ids)
        self.send(json.dumps({"id": ident, "cmd_type": cmd_type, "clear_queue": False, "data": data or {}}))
        ack = self.next("ack")
        assert ack["id"] == ident
        return ack

    def init(self, **data: Any) -> dict[str, Any]:
        return self.command(1, data)

    def frame(self, timestamp: int, payload: bytes | None = None, **fields: Any) -> None:
        self.send(pack_frame(EncodedFrame("jpeg", timestamp, make_jpeg() if payload is None else payload, **fields)))

    def next(self, name: str, timeout: float = 10.0) -> dict[str, Any]:
        """The next event named `name` (its `data`, or the whole message for an ack); others are skipped."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                message = self.events.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                break
            if message["event"] == name:
                return message if name == "ack" else message["data"]
        raise AssertionError(f"no {name} event within {timeout} s")

    def close(self) -> None:
        self.ws.close()
