"""The cameras' own metrics, labelled by `source` (their frames are counted with the robots', `transport="rtsp"`)."""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Counter, Gauge

from netapp.server.sources.watchers import REASONS


class SourceMetrics:
    def __init__(self, registry: CollectorRegistry) -> None:
        r = registry
        self.up = Gauge("netapp_source_up", "1 while the camera's stream gives pictures", ["source"], registry=r)
        self.outages = Counter("netapp_source_outages", "Working streams lost", ["source"], registry=r)
        self.decoded = Counter(
            "netapp_source_pictures_decoded", "Pictures decoded (all; only the newest goes on)", ["source"], registry=r
        )
        self.skipped = Counter(
            "netapp_source_pictures_skipped",
            "Pictures not handed on: corrupt (damaged data, and what follows until a keyframe), packet_too_large",
            ["source", "reason"],
            registry=r,
        )
        self.keyframes_only = Gauge(
            "netapp_source_keyframes_only",
            "1 when decoding could not keep up with the camera and only its keyframes are decoded",
            ["source"],
            registry=r,
        )
        self.subscribers = Gauge("netapp_source_subscribers", "Subscribers of its results", ["source"], registry=r)
        self.watchers_refused = Counter(
            "netapp_source_watchers_refused",
            "WATCHes refused (too_many_subscribers on the camera, too_many_watchers from one address) and watchers "
            "let go (stalled: read nothing)",
            ["reason"],
            registry=r,
        )
        for reason in REASONS:
            self.watchers_refused.labels(reason=reason)
        self.relays = Counter(
            "netapp_source_relays",
            "A camera another replica pulls, relayed to watchers here: connected, refused (not its holder), lost",
            ["source", "outcome"],
            registry=r,
        )
        self.results_written = Counter(
            "netapp_source_results_written", "Results written to --source-results files", ["source"], registry=r
        )

    def add(self, name: str) -> None:
        """Present at 0 from the start, for dashboards and alerts."""
        for metric in (self.up, self.outages, self.decoded, self.keyframes_only, self.subscribers):
            metric.labels(source=name)
        for reason in ("corrupt", "packet_too_large"):
            self.skipped.labels(source=name, reason=reason)
