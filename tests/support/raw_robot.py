"""A bare python-socketio robot for checks of the 5G-ERA wire protocol itself."""

from __future__ import annotations

import queue
import time

import socketio


class RawRobot:
    """A bare python-socketio client that records every event, to check the wire protocol itself."""

    def __init__(self, url: str) -> None:
        self.events: queue.Queue = queue.Queue()
        self.sio = socketio.Client(reconnection=False)
        for event in ("results", "data_error", "message"):
            self.sio.on(event, lambda data, e=event: self.events.put((e, data)), namespace="/data")
        for event in ("command_error", "session_info"):
            self.sio.on(event, lambda data, e=event: self.events.put((e, data)), namespace="/control")
        self.sio.connect(url, namespaces=["/data", "/control"], wait_timeout=10)

    def command(self, payload):
        return self.sio.call("command", payload, namespace="/control", timeout=10)

    def init(self, **data):
        return self.command({"cmd_type": 1, "clear_queue": False, "data": data})

    def frame(self, message, event="image"):
        self.sio.emit(event, message, namespace="/data")

    def next(self, name: str, timeout: float = 10.0):
        return self.next_of(name, timeout=timeout)[1]

    def next_of(self, *names: str, timeout: float = 10.0):
        """(event, data) of the next event named one of `names`; others are skipped."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                event, data = self.events.get(timeout=deadline - time.monotonic())
            except queue.Empty:
                break
            if event in names:
                return event, data
        raise AssertionError(f"no {' or '.join(names)} event within {timeout} s")

    def close(self):
        self.sio.disconnect()
