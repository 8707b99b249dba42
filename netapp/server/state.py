"""What the transports share: settings, sessions, metrics and the pipeline of one app."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from netapp.protocol import TRANSPORTS
from netapp.sdk.processor import Processor
from netapp.server.errors import SessionClosed
from netapp.server.metrics import Metrics
from netapp.server.pipeline import Pipeline
from netapp.server.sessions import Session, SessionRegistry
from netapp.server.settings import Settings
from netapp.server.ui.live import LiveView


@dataclass
class ServerState:
    settings: Settings
    processor: Processor
    sessions: SessionRegistry
    metrics: Metrics
    pipeline: Pipeline
    live: LiveView  # what the /ui pages show
    waiting: int = 0  # `?wait=true` requests waiting for their result (capped by settings.max_waiting)

    @classmethod
    def build(cls, processor: Processor, settings: Settings) -> ServerState:
        sessions = SessionRegistry(settings.results_buffer, settings.max_sessions)
        metrics = Metrics()
        for transport in TRANSPORTS:
            for counter in (metrics.received, metrics.processed, metrics.dropped):
                counter.labels(transport=transport)  # present at 0 from the start, for dashboards and alerts
            metrics.sessions.labels(transport=transport).set_function(lambda t=transport: sessions.count(t))
        live = LiveView()
        pipeline = Pipeline(processor, settings, metrics, sessions, live)
        return cls(settings, processor, sessions, metrics, pipeline, live)

    def close_session(self, session: Session, reason: str) -> None:
        """End a session; the waiters of its queued frames hear `reason`. Its transport closes what it holds."""
        self.sessions.remove(session.id)
        self.pipeline.close(session, SessionClosed(reason))
        self.live.forget(session.id)

    def stats(self, session: Session) -> dict[str, Any]:
        """The session's counters and its queue depth (GET_STATE, /unregister)."""
        return {**session.stats(), "queue_depth": self.pipeline.depth(session)}
