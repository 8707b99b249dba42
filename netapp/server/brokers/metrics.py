"""The publishers' metrics, labelled by `broker`: its redacted URL (scheme, user, hosts; never a password)."""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Counter, Gauge

from netapp.broker.publisher import PublisherEvents

DROP_REASONS = ("count", "bytes", "too_large")


class BrokerMetrics:
    def __init__(self, registry: CollectorRegistry) -> None:
        r = registry
        self.published = Counter(
            "netapp_broker_published", "Results the broker confirmed (at least once)", ["broker"], registry=r
        )
        self.dropped = Counter(
            "netapp_broker_dropped",
            "Results lost from the buffer while the broker was away or slow: count (its buffer= bound), bytes "
            "(buffer_mb=), too_large (one result over the byte bound)",
            ["broker", "reason"],
            registry=r,
        )
        self.up = Gauge("netapp_broker_up", "1 while connected to the broker", ["broker"], registry=r)
        self.waiting = Gauge(
            "netapp_broker_waiting", "Results in the buffer, not yet confirmed", ["broker"], registry=r
        )
        self.waiting_bytes = Gauge(
            "netapp_broker_waiting_bytes", "Bytes of the results in the buffer", ["broker"], registry=r
        )

    def events(self, broker: str) -> PublisherEvents:
        """What one publisher reports, as these metrics (each present at 0 from the start)."""
        self.published.labels(broker=broker)
        for reason in DROP_REASONS:
            self.dropped.labels(broker=broker, reason=reason)
        self.up.labels(broker=broker).set(0)

        def waiting(count: int, size: int) -> None:
            self.waiting.labels(broker=broker).set(count)
            self.waiting_bytes.labels(broker=broker).set(size)

        return PublisherEvents(
            published=self.published.labels(broker=broker).inc,
            dropped=lambda reason: self.dropped.labels(broker=broker, reason=reason).inc(),
            connected=lambda up: self.up.labels(broker=broker).set(int(up)),
            waiting=waiting,
        )
