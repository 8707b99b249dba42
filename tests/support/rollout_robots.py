"""Robots that stream while a model rollout goes on, and waiting for its verdict: the rollout tests of the netapp
and of the middleware's local backend."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import requests

from netapp.client import NetAppClient
from netapp.client.stats import ClientStats

ROBOTS = 8  # the fleet
# Each robot's transport, in turn: a request per frame, Socket.IO, and the binary WebSocket with JPEG and with H.264,
# each held across the swap.
TRANSPORTS = ("http", "ws", "frames", "h264")
# --max-slowdown for the tests that are about agreement, not speed: on a shared 2-core machine one model's p95 over 20
# frames swings by several times under other work (the slow candidate's own test judges speed)
UNJUDGED_SPEED = 50.0
DEADLINE_S = 60.0
# A robot whose frame goes unanswered this long has lost it (on a loaded machine a first frame, with 8 robots
# connecting and the model warming up, can take several seconds)
RESULT_TIMEOUT_S = 30.0


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
    stats: ClientStats | None = None  # the client's own counters, kept once it has stopped

    def run(self, stop: threading.Event) -> None:
        with NetAppClient(
            self.url, transport=self.transport, max_in_flight=1, token=self.token, robot_id=self.robot_id
        ) as client:
            self.stats = client.stats
            while not stop.is_set():
                client.send(self.image)
                self.sent += 1
                result = next(client.results(timeout=RESULT_TIMEOUT_S), None)
                if result is None:
                    self.errors.append(f"no result within {RESULT_TIMEOUT_S:g} s")
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
    def __init__(
        self, url: str, image, token: str | None = None, robot_ids: list[str] | None = None, robots: int = ROBOTS
    ) -> None:
        self.stop = threading.Event()
        ids = robot_ids or [None] * robots
        self.robots = [
            Robot(url, image, token=token, robot_id=r, transport=TRANSPORTS[i % len(TRANSPORTS)])
            for i, r in enumerate(ids)
        ]
        for robot in self.robots:
            robot.thread = threading.Thread(target=robot.run, args=(self.stop,), daemon=True)
            robot.thread.start()

    def answered(self) -> list[int]:
        return [r.answered for r in self.robots]

    def streamed(self, since: list[int], more: int = 5) -> None:
        """Wait until each robot has had `more` results after `since` (its `answered()` then), so that each
        streamed across what happened in between; every one so far without an error."""
        deadline = time.monotonic() + DEADLINE_S
        while time.monotonic() < deadline and any(
            r.answered < start + more and not r.errors for r, start in zip(self.robots, since, strict=True)
        ):
            time.sleep(0.05)  # polling the robots' counts with a deadline
        assert [r.errors for r in self.robots] == [[]] * len(self.robots)
        assert all(r.answered >= start + more for r, start in zip(self.robots, since, strict=True)), (
            self.answered(),
            since,
        )

    def finish(self, min_answers: int = 5) -> None:
        """Once each robot has had `min_answers` results (so that each streamed across the verdict), stop them:
        every frame sent was answered, none with an error, by the test's count and by the clients' own."""
        self.streamed([0] * len(self.robots), min_answers)
        self.stop.set()
        for robot in self.robots:
            robot.thread.join(timeout=15)
        assert [r.errors for r in self.robots] == [[]] * len(self.robots)
        assert all(r.sent == r.answered > 0 for r in self.robots), [(r.sent, r.answered) for r in self.robots]
        counters = [(r.transport, r.stats.sent, r.stats.results, r.stats.errors, r.stats.lost) for r in self.robots]
        assert all(sent == results and errors == lost == 0 for _, sent, results, errors, lost in counters), counters


def wait_for_verdict(url: str) -> dict:
    deadline = time.monotonic() + DEADLINE_S
    while time.monotonic() < deadline:
        state = requests.get(url + "/rollout", timeout=5).json()
        if state["phase"] in ("promoted", "rolled_back"):
            return state
        time.sleep(0.05)  # polling the state with a deadline
    raise AssertionError(f"no verdict within {DEADLINE_S} s: {state}")
