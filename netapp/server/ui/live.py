"""What the pages show, kept beside the data path at almost no cost.

For every session: a bounded history of each result's latency parts (one deque append per result). Only while a
page watches a robot: a reference to its latest decoded frame and result, JPEG-encoded when the page asks for it
(at most once per result, however many pages watch). Nobody watching: no frame is kept and nothing is encoded.

Uplink and downlink happen on the robot's clock: a robot may report them for its previous result (NetAppClient does:
Socket.IO `metadata.latency`, `frames` its JSON part's `latency`, HTTP `X-Robot-Latency`), bounded and checked here; the
netapp measures the queue and the inference itself.
"""

from __future__ import annotations

import asyncio
import json
import math
import secrets
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from netapp.server.sessions import Session

HISTORY = 120  # results per robot for the chart and the percentiles
RATE_WINDOW_S = 5.0
MAX_REPORTED_MS = 600_000.0


def robot_latency(value: Any) -> tuple[float, float] | None:
    """A robot's report {"uplink_ms": x, "downlink_ms": y} (a dict, or its JSON of at most 200 characters);
    None for anything else, which is ignored (the report is optional and never refuses a frame)."""
    if isinstance(value, str):
        if len(value) > 200:
            return None
        try:
            value = json.loads(value)
        except ValueError:
            return None
    if not isinstance(value, dict):
        return None
    parts = (value.get("uplink_ms"), value.get("downlink_ms"))
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in parts):
        return None
    if not all(0 <= v <= MAX_REPORTED_MS for v in parts):
        return None
    return float(parts[0]), float(parts[1])


def percentile(values: list[float], q: float) -> float | None:
    if not values:
        return None
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, round(q / 100 * len(ordered) + 0.5) - 1))]


@dataclass
class RobotView:
    """One session as the pages see it; `id` is a page id, never the session id (which authorises frames)."""

    id: str
    session: Session
    history: deque[dict[str, Any]] = field(default_factory=lambda: deque(maxlen=HISTORY))
    reported: tuple[float, float] | None = None  # the robot's last (uplink, downlink)
    watchers: int = 0
    latest: tuple[np.ndarray, dict[str, Any]] | None = None  # only while watched
    version: int = 0  # of `latest`
    encoded: tuple[int, bytes] | None = None  # (version, JPEG) shared by the watchers
    changed: asyncio.Event = field(default_factory=asyncio.Event)

    def summary(self) -> dict[str, Any]:
        now = time.monotonic()
        recent = [h for h in self.history if now - h["at"] <= RATE_WINDOW_S]
        totals = [h["total_ms"] for h in self.history]
        s = self.session
        return {
            "id": self.id,
            "robot_id": s.robot_id,
            "transport": s.label,
            "results_per_s": round(len(recent) / RATE_WINDOW_S, 1),
            "latency_p50_ms": _round(percentile(totals, 50)),
            "latency_p95_ms": _round(percentile(totals, 95)),
            "frame_size": f"{s.frame_size[0]}x{s.frame_size[1]}" if s.frame_size else None,
            "kb_per_frame": round(s.frame_bytes / 1000, 1) if s.frame_bytes else None,
            "received": s.received,
            "processed": s.processed,
            "dropped": s.dropped,
            "rejected": s.rejected,
            "watchers": self.watchers,
        }


def _round(value: float | None) -> float | None:
    return None if value is None else round(value, 1)


class LiveView:
    """The pages' view of every session (see the module docstring). Runs on the event loop."""

    def __init__(self, max_watchers: int = 16) -> None:
        self.max_watchers = max_watchers
        self._by_session: dict[str, RobotView] = {}
        self._by_id: dict[str, RobotView] = {}

    def _view(self, session: Session) -> RobotView:
        view = self._by_session.get(session.id)
        if view is None:
            view = RobotView(secrets.token_hex(6), session)
            self._by_session[session.id] = view
            self._by_id[view.id] = view
        return view

    def watched(self, session_id: str) -> bool:
        """Whether to keep this session's decoded frames (called for each frame on the decoding thread)."""
        view = self._by_session.get(session_id)
        return view is not None and view.watchers > 0

    def report(self, session: Session, value: Any) -> None:
        """The robot's own uplink and downlink of its previous result, when it sends them."""
        parts = robot_latency(value)
        if parts is not None:
            self._view(session).reported = parts

    def record(self, session: Session, message: dict[str, Any], image: np.ndarray | None) -> None:
        """A result delivered: its latency parts into the history; the frame too while a page watches."""
        view = self._view(session)
        queue = (message["timestamp_before_process"] - message["recv_timestamp"]) / 1e6
        inference = (message["timestamp_after_process"] - message["timestamp_before_process"]) / 1e6
        reply = (message["send_timestamp"] - message["timestamp_after_process"]) / 1e6
        uplink, downlink = view.reported if view.reported else (None, None)
        entry = {
            "at": time.monotonic(),
            "uplink_ms": uplink,
            "queue_ms": round(queue, 2),
            "inference_ms": round(inference, 2),
            "downlink_ms": downlink if downlink is not None else None,
            "total_ms": (uplink or 0) + queue + inference + (downlink if downlink is not None else reply),
        }
        view.history.append(entry)
        if view.watchers > 0 and image is not None:
            view.latest = (image, message)
            view.version += 1
            view.changed.set()

    def forget(self, session_id: str) -> None:
        view = self._by_session.pop(session_id, None)
        if view is not None:
            self._by_id.pop(view.id, None)
            view.latest = view.encoded = None
            view.changed.set()  # its pages see it gone

    def robots(self) -> list[RobotView]:
        return [v for v in self._by_session.values() if not v.session.closed]

    def get(self, view_id: str) -> RobotView | None:
        view = self._by_id.get(view_id)
        return view if view is not None and not view.session.closed else None

    def total_watchers(self) -> int:
        return sum(v.watchers for v in self._by_session.values())

    def watch(self, view: RobotView) -> None:
        view.watchers += 1

    def unwatch(self, view: RobotView) -> None:
        view.watchers = max(0, view.watchers - 1)
        if view.watchers == 0:  # nobody looks: hold no frame
            view.latest = view.encoded = None
