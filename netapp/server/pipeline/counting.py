"""Every frame is counted here and only here: received, rejected, dropped, dropped for its deadline and processed,
in the session's counters and the Prometheus metrics together, labelled by the transport the frame arrived on."""

from __future__ import annotations

from netapp.server.metrics import Metrics
from netapp.server.sessions import Session


class FrameCounter:
    def __init__(self, metrics: Metrics) -> None:
        self.metrics = metrics
        self.recent_latency_s = 0.0  # moving average of receive-to-result (a gauge to scale on)
        metrics.recent_latency.set_function(lambda: self.recent_latency_s)

    def received(self, session: Session | None, transport: str) -> None:
        self.metrics.received.labels(transport=transport).inc()
        if session is not None:
            session.admit(transport)

    def rejected(self, session: Session | None, transport: str, reason: str) -> None:
        """A frame (or command) refused with an error to its sender."""
        if session is not None:
            session.rejected += 1
        self.metrics.reject(transport, reason)

    def dropped(self, session: Session, transport: str) -> None:
        """Superseded by a newer frame of its robot (newest wins)."""
        session.dropped += 1
        self.metrics.dropped.labels(transport=transport).inc()

    def deadline_dropped(self, session: Session, transport: str) -> None:
        session.deadline_dropped += 1
        self.metrics.deadline_dropped.labels(transport=transport).inc()

    def processed(self, session: Session, transport: str, latency_s: float) -> None:
        session.processed += 1
        self.metrics.processed.labels(transport=transport).inc()
        self.metrics.latency.labels(transport=transport).observe(latency_s)
        self.recent_latency_s += 0.05 * (latency_s - self.recent_latency_s)
