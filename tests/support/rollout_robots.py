"""Robots that stream while a model rollout goes on, and waiting for its verdict: the rollout tests of the netapp
and of the middleware's local backend."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import requests

from netapp.client import NetAppClient

ROBOTS = 4
# --max-slowdown for the tests that are about agreement, not speed: on a shared 2-core machine one model's p95 over 20
# frames swings by several times under other work (the slow candidate's own test judges speed)
UNJUDGED_SPEED = 50.0
DEADLINE_S = 60.0


@dataclass
class Robot:
    """A robot streaming one frame at a time (each after the previous result) until told to stop."""

    url: str
    image: object
    sent: int = 0
    answered: int = 0
    errors: list[str] = field(default_factory=list)
    token: str | None = None
    robot_id: str | None = None
    transport: str = "http"
    thread: threading.Thread | None = None

    def run(self, stop: threading.Event) -> None:
        with NetAppClient(
            self.url, transport=self.transport, max_in_flight=1, token=self.token, robot_id=self.robot_id
        ) as client:
            while not stop.is_set():
                client.send(self.image)
                self.sent += 1
                result = next(client.results(timeout=10), None)
                if result is None:
                    self.errors.append("no result within 10 s")
                    return
                if "error" in result.message or "detections" not in result.message:
                    self.errors.append(str(result.message)[:200])
                self.answered += 1


def reexport(model: Path, to: Path) -> Path:
    """A re-export of `model`: the same weights, saved again by onnx as another file (a candidate that agrees)."""
    import onnx

    onnx.save(onnx.load(str(model)), str(to))
    return to


class Fleet:
    def __init__(self, url: str, image, token: str | None = None, robot_ids: list[str] | None = None) -> None:
        self.stop = threading.Event()
        ids = robot_ids or [None] * ROBOTS
        transports = ("http", "frames")  # a request per frame, and a WebSocket held across the swap
        self.robots = [
            Robot(url, image, token=token, robot_id=r, transport=transports[i % 2]) for i, r in enumerate(ids)
        ]
        for robot in self.robots:
            robot.thread = threading.Thread(target=robot.run, args=(self.stop,), daemon=True)
            robot.thread.start()

    def finish(self, min_answers: int = 5) -> None:
        """Once each robot has had `min_answers` results (so that each streamed across the verdict), stop them:
        every frame sent was answered, none with an error."""
        deadline = time.monotonic() + DEADLINE_S
        while any(r.answered < min_answers and not r.errors for r in self.robots) and time.monotonic() < deadline:
            time.sleep(0.05)  # polling the robots' counts with a deadline
        self.stop.set()
        for robot in self.robots:
            robot.thread.join(timeout=15)
        assert [r.errors for r in self.robots] == [[]] * len(self.robots)
        assert all(r.sent == r.answered > 0 for r in self.robots), [(r.sent, r.answered) for r in self.robots]


def wait_for_verdict(url: str) -> dict:
    deadline = time.monotonic() + DEADLINE_S
    while time.monotonic() < deadline:
        state = requests.get(url + "/rollout", timeout=5).json()
        if state["phase"] in ("promoted", "rolled_back"):
            return state
        time.sleep(0.05)  # polling the state with a deadline
    raise AssertionError(f"no verdict within {DEADLINE_S} s: {state}")
