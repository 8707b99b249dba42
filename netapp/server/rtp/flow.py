"""One RTP session's gate: which datagrams reach its depacketiser. Pure (the caller passes the time).

Checked in this order, each refusal counted under its reason and nothing else changed: the session's packet and
byte rates (a flood is refused before any parsing: `flood`), the sender's address (`stranger`: not the address the
robot declared, or not the first sender seen), RTCP on the RTP port (`rtcp`, ignored), the RTP header (`malformed`,
`too_large`), the payload type (`wrong_payload_type`) and the SSRC the session was given (`wrong_ssrc`, a token of
32 random bits: a stranger who guesses the port still needs it, and the first sender is bound only once it has it).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from netapp.rtp.packet import RtpError, RtpPacket, is_rtcp, parse
from netapp.server.rtp.request import RtpRequest

Address = tuple[str, int]


@dataclass
class Bucket:
    """A token bucket: `rate` per second, up to `burst`."""

    rate: float
    burst: float
    level: float = -1.0
    at: float = 0.0

    def take(self, amount: float, now: float) -> bool:
        if self.level < 0:
            self.level, self.at = self.burst, now
        self.level = min(self.burst, self.level + (now - self.at) * self.rate)
        self.at = now
        if self.level < amount:
            return False
        self.level -= amount
        return True


@dataclass
class Flow:
    request: RtpRequest
    ssrc: int
    max_packets_per_s: float
    max_bytes_per_s: float
    sender: Address | None = None  # bound at the first good packet (or the declared address's first)
    _packets: Bucket = field(init=False)
    _bytes: Bucket = field(init=False)

    def __post_init__(self) -> None:
        # A second's worth at once: a keyframe arrives as a burst of packets.
        self._packets = Bucket(self.max_packets_per_s, self.max_packets_per_s)
        self._bytes = Bucket(self.max_bytes_per_s, self.max_bytes_per_s)

    def admit(self, datagram: bytes, sender: Address, now: float) -> RtpPacket | str:
        """The packet, or why it is dropped (see the module)."""
        if self.sender is not None and sender != self.sender:
            return "stranger"  # before the buckets: a stranger's flood must not use up the robot's rate
        if self.request.address is not None and sender[0] != self.request.address:
            return "stranger"
        if not self._packets.take(1, now) or not self._bytes.take(len(datagram), now):
            return "flood"
        if is_rtcp(datagram):
            return "rtcp"
        try:
            packet = parse(datagram)
        except RtpError as exc:
            return exc.reason
        if packet.payload_type != self.request.payload_type:
            return "wrong_payload_type"
        if packet.ssrc != self.ssrc:
            return "wrong_ssrc"
        if self.sender is None:
            self.sender = sender
        return packet

    def rtcp_address(self) -> Address | None:
        """Where an RTCP PLI for this stream goes (None before a sender is known)."""
        if self.sender is None:
            return None
        if self.request.rtcp_mux:
            return self.sender
        return (self.sender[0], self.request.rtcp_port or self.sender[1] + 1)


DROP_REASONS = (
    "stranger",
    "flood",
    "rtcp",
    "malformed",
    "too_large",
    "wrong_payload_type",
    "wrong_ssrc",
    # the depacketiser's (`netapp.rtp.depacketize`)
    "late",
    "gap",
    "incomplete",
    "too_many_nals",
    "waiting_keyframe",
    "timeout",
)
