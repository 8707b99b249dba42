"""RTP's own metrics (its access units are counted as frames with the robots', `transport="rtp"`)."""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Counter, Gauge

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
        self.ports_free = Gauge("netapp_rtp_ports_free", "Ports of --rtp-ports not held by a session", registry=r)
        self.refused = Counter(
            "netapp_rtp_sessions_refused", "RTP sessions refused: bad_rtp, rtp_ports_full", ["reason"], registry=r
        )
        for reason in DROP_REASONS:
            self.dropped.labels(reason=reason)
