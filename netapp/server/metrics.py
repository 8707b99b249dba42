"""Prometheus metrics, one registry per app so several apps can live in one process (tests, SDK users)."""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest

from netapp.protocol import METRIC_LATENCY, METRIC_LOAD, METRIC_QUEUE, METRIC_ROBOTS

LATENCY_BUCKETS = (0.005, 0.01, 0.02, 0.03, 0.05, 0.075, 0.1, 0.15, 0.2, 0.3, 0.5, 0.75, 1.0, 2.0, 5.0)


class Metrics:
    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        r = self.registry
        self.received = Counter("netapp_frames_received", "Frames received", ["transport"], registry=r)
        self.processed = Counter("netapp_frames_processed", "Frames processed", ["transport"], registry=r)
        self.dropped = Counter(
            "netapp_frames_dropped", "Frames superseded by a newer frame of the same robot", ["transport"], registry=r
        )
        self.deadline_dropped = Counter(
            "netapp_frames_deadline_dropped",
            "Frames dropped before inference: they could not finish within the robot's deadline",
            ["transport"],
            registry=r,
        )
        self.rejected = Counter(
            "netapp_frames_rejected", "Frames refused with an error to the sender", ["transport", "reason"], registry=r
        )
        self.trace_context_ignored = Counter(
            "netapp_trace_context_ignored",
            "Frames whose traceparent was malformed: ignored, as W3C says (the frame was served, traced as a root)",
            registry=r,
        )
        self.result_fields_refused = Counter(
            "netapp_result_fields_refused",
            "Parts of a processor's results refused before sending (a mask, keypoints or rbox too big or malformed, "
            "detections or classifications past their bound); the rest of the result was sent",
            ["reason"],
            registry=r,
        )
        self.results_overflowed = Counter(
            "netapp_results_overflowed",
            "Results discarded because the robot did not fetch (HTTP polling) or read (frames) them",
            registry=r,
        )
        self.forwarded = Counter(
            "netapp_forwarded",
            "Requests (http) and WebSockets (websocket) of sessions another replica owns, forwarded to it",
            ["kind"],
            registry=r,
        )
        for kind in ("http", "websocket"):
            self.forwarded.labels(kind=kind)  # present at 0 from the start
        self.peer_tls_refused = Counter(
            "netapp_peer_tls_refused",
            "Connections to another replica that failed their TLS handshake: its certificate is not one the peer CA "
            "vouches for (certificate), or another TLS failure (handshake)",
            ["reason"],
            registry=r,
        )
        self.sessions_refused = Counter(
            "netapp_sessions_refused",
            "Robots turned away: the netapp already held its limit of sessions (SessionsFull)",
            registry=r,
        )
        self.sessions = Gauge("netapp_active_sessions", "Open robot sessions", ["transport"], registry=r)
        self.queue_depth = Gauge(METRIC_QUEUE, "Frames waiting for inference, all sessions", registry=r)
        self.latency = Histogram(
            "netapp_latency_seconds", "Receive to send, per frame", ["transport"], buckets=LATENCY_BUCKETS, registry=r
        )
        self.inference = Histogram(
            "netapp_inference_seconds", "Processor time per batch", buckets=LATENCY_BUCKETS, registry=r
        )
        self.capacity_robots = Gauge(
            "netapp_capacity_robots",
            "Robots this replica can serve, from its measured capacity: optimal (each at its full input rate) and "
            "hard (past it new robots are refused); NaN before the first batch is measured",
            ["kind"],
            registry=r,
        )
        self.robots = Gauge(METRIC_ROBOTS, "Robots (open sessions) this replica serves", registry=r)
        self.capacity_fps = Gauge(
            "netapp_capacity_results_per_second", "Results per second the inference thread can sustain", registry=r
        )
        self.demand_fps = Gauge("netapp_robot_input_fps", "The median robot's input rate, FPS", registry=r)
        self.load = Gauge(METRIC_LOAD, "Robots served over the optimal limit (1: at it), to scale on", registry=r)
        self.recent_latency = Gauge(METRIC_LATENCY, "Receive to result, moving average over recent frames", registry=r)
        self.batch_size = Histogram(
            "netapp_batch_size", "Frames per inference batch", buckets=(1, 2, 4, 8, 16, 32), registry=r
        )

    def reject(self, transport: str, reason: str) -> None:
        self.rejected.labels(transport=transport, reason=reason).inc()

    def render(self) -> bytes:
        return generate_latest(self.registry)
