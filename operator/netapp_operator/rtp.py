"""A NetApp's `spec.rtp` (H.264 over RTP/UDP pushed by robots, docs/cameras.md#rtp-push): checked, and rendered as
the netapp's `--rtp-ports`, its container's and Service's UDP ports and its NetworkPolicy's (pure functions).

A Service lists each port (Kubernetes has no port ranges in Services), so the range is small. kube-proxy sends each
UDP flow to any ready replica, not to the one that holds the robot's session: RTP needs one replica. A NodePort
Service reaches a node's port only in the cluster's node-port range (30000-32767 by default): there the operator
makes each UDP port's nodePort the port itself, so the port the netapp answers is the one a robot reaches.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from netapp.server.rtp.ports import parse_port_range

MAX_RTP_PORTS = 64  # one per RTP session; each is a Service port
NODE_PORTS = range(30000, 32768)  # Kubernetes' default --service-node-port-range


@dataclasses.dataclass(frozen=True)
class RtpSpec:
    first_port: Any
    count: Any = 8

    @property
    def ports(self) -> range:
        return range(int(self.first_port), int(self.first_port) + int(self.count))


def parse_rtp(raw: Any) -> RtpSpec | None:
    if raw is None:
        return None
    raw = raw if isinstance(raw, Mapping) else {}
    return RtpSpec(first_port=raw.get("firstPort"), count=raw.get("count", 8))


def rtp_problems(rtp: RtpSpec | None, replicas: Any, autoscaled: bool) -> list[str]:
    """What is wrong with `spec.rtp`, as sentences."""
    if rtp is None:
        return []
    first, count = rtp.first_port, rtp.count
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in (first, count)):
        return ["spec.rtp needs integers firstPort and count, e.g. {firstPort: 31000, count: 8}"]
    if not 1 <= count <= MAX_RTP_PORTS:
        return [f"spec.rtp.count must be in 1..{MAX_RTP_PORTS} (one UDP port per RTP session), got {count}"]
    try:
        parse_port_range(f"{first}-{first + count - 1}")
    except ValueError as exc:
        return [f"spec.rtp: {str(exc).replace('--rtp-ports', 'the ports')}"]
    if replicas != 1 or autoscaled:
        return ["spec.rtp needs replicas: 1 and no autoscaling: a Service sends UDP to any replica, not the session's"]
    return []


def rtp_args(rtp: RtpSpec | None) -> list[str]:
    if rtp is None:
        return []
    ports = rtp.ports
    return ["--rtp-ports", f"{ports.start}-{ports.stop - 1}"]


def container_ports(rtp: RtpSpec | None) -> list[dict[str, Any]]:
    return [] if rtp is None else [{"name": _name(i), "containerPort": p, "protocol": "UDP"} for i, p in _each(rtp)]


def service_ports(rtp: RtpSpec | None, service_type: str) -> list[dict[str, Any]]:
    """The UDP ports of the Service: the same number outside and in; a NodePort Service's nodePort is the port too
    when it lies in the node-port range (else Kubernetes picks one, and the robot cannot know it)."""
    if rtp is None:
        return []
    ports = []
    for i, port in _each(rtp):
        entry: dict[str, Any] = {"name": _name(i), "port": port, "targetPort": port, "protocol": "UDP"}
        if service_type in ("NodePort", "LoadBalancer") and port in NODE_PORTS:
            entry["nodePort"] = port
        ports.append(entry)
    return ports


def policy_ports(rtp: RtpSpec | None) -> list[dict[str, Any]]:
    if rtp is None:
        return []
    ports = rtp.ports
    return [{"port": ports.start, "endPort": ports.stop - 1, "protocol": "UDP"}]


def _each(rtp: RtpSpec) -> list[tuple[int, int]]:
    return list(enumerate(rtp.ports))


def _name(index: int) -> str:
    return f"rtp-{index}"  # a port's name: at most 15 characters
