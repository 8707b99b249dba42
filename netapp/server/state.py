"""What the transports share: settings, sessions, metrics and the pipeline of one app."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from netapp.protocol import TRANSPORTS
from netapp.sdk.processor import Processor
from netapp.server.cluster import Cluster
from netapp.server.errors import SessionClosed
from netapp.server.metrics import Metrics
from netapp.server.pipeline import Pipeline
from netapp.server.sessions import Session, SessionRegistry
from netapp.server.settings import Settings


@dataclass
class ServerState:
    settings: Settings
    processor: Processor
    sessions: SessionRegistry
    metrics: Metrics
    pipeline: Pipeline
    waiting: int = 0  # `?wait=true` requests waiting for their result (capped by settings.max_waiting)
    cluster: Cluster = field(default_factory=lambda: Cluster.build(None, None))
    draining: bool = False  # SIGTERM: robots are moving elsewhere (netapp.server.replica)

    @classmethod
    def build(cls, processor: Processor, settings: Settings) -> ServerState:
        sessions = SessionRegistry(settings.results_buffer, settings.max_sessions)
        metrics = Metrics()
        for transport in TRANSPORTS:
            for counter in (metrics.received, metrics.processed, metrics.dropped):
                counter.labels(transport=transport)  # present at 0 from the start, for dashboards and alerts
            metrics.sessions.labels(transport=transport).set_function(lambda t=transport: sessions.count(t))
        cluster = Cluster.build(settings.cluster_key, settings.advertise_url)
        pipeline = Pipeline(processor, settings, metrics, sessions)
        return cls(settings, processor, sessions, metrics, pipeline, cluster=cluster)

    def close_session(self, session: Session, reason: str, *, revoke: bool = False) -> None:
        """End a session; the waiters of its queued frames hear `reason`. Its transport closes what it holds.
        `revoke`: its id is refused from now on (an unregistered HTTP token; an idle one may come back)."""
        self.sessions.remove(session.id, revoke=revoke)
        self.pipeline.close(session, SessionClosed(reason))

    def stats(self, session: Session) -> dict[str, Any]:
        """The session's counters and its queue depth (GET_STATE, /unregister)."""
        return {**session.stats(), "queue_depth": self.pipeline.depth(session)}
