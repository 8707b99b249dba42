"""RTP's own metrics (its access units are counted as frames with the robots', `transport="rtp"`)."""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram

from netapp.server.rtp.flow import DROP_REASONS


class RtpMetrics:
    def __init__(self, registry: CollectorRegistry) -> None:
        r = registry
        self.packets = Counter("netapp_rtp_packets", "RTP datagrams received on the sessions' ports", registry=r)
        self.dropped = Counter(
            "netapp_rtp_dropped",
            "RTP datagrams (or access units) dropped, by reason: stranger, flood, malformed, wrong_payload_type, "
            "wrong_ssrc, gap, waiting_keyframe, ...",
            ["reason"],
            registry=r,
        )
        self.keyframe_requests = Counter(
            "netapp_rtp_keyframe_requests", "Keyframes asked for (RTCP PLI and the session's transport)", registry=r
        )
        self.nacked = Counter("netapp_rtp_nacked", "RTP packets asked for again (RTCP generic NACK)", registry=r)
        self.recovered = Counter(
            "netapp_rtp_recovered", "RTP packets asked for again that came before their gap was given up", registry=r
        )
        self.recovery = Histogram(
            "netapp_rtp_recovery_seconds",
            "From a missing RTP packet's first NACK to its arrival",
            buckets=(0.02, 0.04, 0.06, 0.08, 0.1, 0.15, 0.2, 0.3, 0.5, 1.0),
            registry=r,
        )
        self.given_up = Counter(
            "netapp_rtp_given_up",
            "RTP packets asked for again that never came in time (their pictures lost)",
            registry=r,
        )
        self.restarts = Counter(
            "netapp_rtp_restarts",
            "RTP streams started again at a sequence number too far ahead to wait for the gap (netapp.rtp.reorder)",
            registry=r,
        )
        self.tail_probes = Counter(
            "netapp_rtp_tail_probes",
            "Pictures whose end did not come in a burst with the rest: the packet after asked for (NACK)",
            registry=r,
        )
        self.results_udp = Counter(
            "netapp_rtp_results_udp",
            "Results sent back over UDP as well (RTCP APP), by outcome: sent, too_large (the transport's copy only)",
            ["outcome"],
            registry=r,
        )
        self.ports_free = Gauge("netapp_rtp_ports_free", "Ports of --rtp-ports not held by a session", registry=r)
        self.refused = Counter(
            "netapp_rtp_sessions_refused", "RTP sessions refused: bad_rtp, rtp_ports_full", ["reason"], registry=r
        )
        for outcome in ("sent", "too_large"):
            self.results_udp.labels(outcome=outcome)
        for reason in DROP_REASONS:
            self.dropped.labels(reason=reason)
