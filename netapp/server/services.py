"""What one app holds: its settings, sessions, metrics, pipeline and cluster, built together (the dataplane, the
transports, the heartbeat and the replica front all work over these)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

from netapp.protocol import FRAMES_H264_LABEL, MEASURED_ADMISSION, TRANSPORTS
from netapp.sdk.processor import Processor, StatefulProcessor
from netapp.server.capacity import CapacityLimits
from netapp.server.cluster.ownership import Cluster
from netapp.server.cluster.peer_tls import PeerTLS
from netapp.server.cluster.revocation import RevocationCheck
from netapp.server.metrics import Metrics
from netapp.server.pipeline.pipeline import Pipeline
from netapp.server.pipeline.tracing import FrameTracing
from netapp.server.rollout.candidates import candidate_factory
from netapp.server.rollout.metrics import RolloutMetrics
from netapp.server.rollout.rollout import Rollout
from netapp.server.sessions import SessionRegistry
from netapp.server.settings import Settings
from netapp.tracing import Tracer, tracer_from_env

SERVICE_NAME = "netapp"  # its traces' service.name unless OTEL_SERVICE_NAME says otherwise


@dataclass
class NetAppServices:
    settings: Settings
    processor: Processor
    sessions: SessionRegistry
    metrics: Metrics
    pipeline: Pipeline
    waiting: int = 0  # `?wait=true` requests waiting for their result (capped by settings.max_waiting)
    cluster: Cluster = field(default_factory=lambda: Cluster.build(None, None))
    draining: bool = False  # SIGTERM: robots are moving elsewhere (netapp.server.cluster.replica)
    revocations: RevocationCheck | None = None  # asks a token's owner whether it was unregistered there
    peers: PeerTLS | None = None  # how this replica connects to the others (TLS verified against the peer CA)

    @classmethod
    def build(cls, processor: Processor, settings: Settings, tracer: Tracer | None = None) -> NetAppServices:
        """`tracer`: where sampled frames' spans go (docs/tracing.md); None: as the OTel variables say (off unless
        OTEL_EXPORTER_OTLP_ENDPOINT is set)."""
        sessions = SessionRegistry(settings.results_buffer, live_s=settings.live_session_s)
        metrics = Metrics()
        for transport in (*TRANSPORTS, FRAMES_H264_LABEL):
            for counter in (metrics.received, metrics.processed, metrics.dropped, metrics.deadline_dropped):
                counter.labels(transport=transport)  # present at 0 from the start, for dashboards and alerts
            metrics.sessions.labels(transport=transport).set_function(lambda t=transport: sessions.count(t))
        cluster = Cluster.build(settings.cluster_key, settings.advertise_url)
        tracer = tracer if tracer is not None else tracer_from_env(SERVICE_NAME)
        tracing = FrameTracing(tracer, metrics.trace_context_ignored.inc) if tracer is not None else None
        pipeline = Pipeline(processor, settings, metrics, sessions, tracing)
        state = cls(settings, processor, sessions, metrics, pipeline, cluster=cluster)
        state.peers = PeerTLS(settings.peer_ca, metrics.peer_tls_refused)
        state.revocations = RevocationCheck(cluster, state.peers)
        sessions.limit = state.admission_limit
        pipeline.attach(
            Rollout(
                lambda: state.processor,
                state.promote,
                candidate_factory(processor),
                RolloutMetrics(metrics.registry),
                lanes=pipeline.lanes,
            )
        )
        state._publish_capacity()
        return state

    @property
    def rollout(self) -> Rollout:
        assert isinstance(self.pipeline.hook, Rollout)
        return self.pipeline.hook

    async def promote(self, candidate: Processor) -> None:
        """Serve `candidate` instead of the current model, swapped between batches on an inference thread."""

        def swap() -> None:
            self.processor = candidate
            self.pipeline.swap_processor(candidate)

        await self.pipeline.exclusive(swap)

    def capacity(self) -> CapacityLimits:
        """This replica's measured capacity and robot limits, now."""
        return self.pipeline.capacity.limits(self.sessions.input_rates(time.monotonic()))

    def admission_limit(self) -> tuple[int, str]:
        """Sessions past which a new robot is refused, and why that many: the session cap; with `--admission
        measured`, the lower of it and the capacity's hard limit once measured. The one admission check
        (`SessionRegistry.create`) asks this."""
        if self.settings.admission == MEASURED_ADMISSION:
            hard = self.pipeline.capacity.admission_limit(self.sessions.input_rates(time.monotonic()))
            if hard is not None and hard < self.settings.max_sessions:
                return hard, "its measured capacity"
        return self.settings.max_sessions, "its session cap"

    def _publish_capacity(self) -> None:
        m = self.metrics
        nan = math.nan
        m.capacity_robots.labels(kind="optimal").set_function(lambda: _or_nan(self.capacity().optimal))
        m.capacity_robots.labels(kind="hard").set_function(lambda: _or_nan(self.capacity().hard))
        m.robots.set_function(lambda: len(self.sessions))
        m.capacity_fps.set_function(lambda: _or_nan(self.capacity().capacity_fps))
        m.demand_fps.set_function(lambda: self.capacity().demand_fps)
        m.load.set_function(lambda: len(self.sessions) / (self.capacity().optimal or nan))

    @property
    def stateful(self) -> bool:
        """Whether the processor keeps a state per session (then a session lives on one replica)."""
        return isinstance(self.processor, StatefulProcessor)


def _or_nan(value: float | None) -> float:
    return math.nan if value is None else float(value)
