"""Packets put back in sequence order before the depacketiser, a gap waited for while it is asked for again (RTCP
generic NACK, RFC 4585): pure, bounded, the time passed in.

A gap is asked for at once and again every RENACK_S, and waited for up to `hold_s` (a few round trips); then it is
given up, and the depacketiser sees the jump in sequence numbers (a loss: the pictures until the next keyframe). A
sender that ignores NACKs (GStreamer's `udpsink` alone) costs only that wait on each loss.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from netapp.rtp.packet import RtpPacket, sequence_after

HOLD_S = 0.12  # three round trips of 40 ms
RENACK_S = 0.04
MAX_HELD = 512  # packets waiting behind a gap: past it the gap is given up at once


@dataclass
class Reorder:
    hold_s: float = HOLD_S
    max_held: int = MAX_HELD
    _expected: int | None = None
    _held: dict[int, RtpPacket] = field(default_factory=dict)  # by sequence number
    _missing: dict[int, tuple[float, float]] = field(default_factory=dict)  # seq -> (first missed, last asked)

    def push(self, packet: RtpPacket, now: float) -> tuple[list[RtpPacket] | None, list[int]]:
        """(the packets now in order, None for a late or duplicate one; the sequence numbers to ask for now)."""
        if self._expected is None:
            self._expected = packet.sequence
        step = sequence_after(self._expected, packet.sequence)
        if step < 0 or packet.sequence in self._held:
            return None, []
        self._held[packet.sequence] = packet
        asked = []
        for k in range(step):
            sequence = (self._expected + k) & 0xFFFF
            if sequence not in self._held and sequence not in self._missing:
                self._missing[sequence] = (now, now)
                asked.append(sequence)
        ready = self._release()
        if len(self._held) > self.max_held:
            ready += self._give_up()
        return ready, asked

    def tick(self, now: float) -> tuple[list[RtpPacket], list[int]]:
        """Give up the gaps waited for `hold_s`; the ones to ask for again."""
        ready: list[RtpPacket] = []
        if any(now - first >= self.hold_s for first, _ in self._missing.values()):
            ready = self._give_up()
        asked = []
        for sequence, (first, last) in self._missing.items():
            if now - last >= RENACK_S:
                self._missing[sequence] = (first, now)
                asked.append(sequence)
        return ready, asked

    def next_deadline(self) -> float | None:
        """When `tick` has something to do (monotonic seconds), None while nothing is missing."""
        if not self._missing:
            return None
        return min(min(first + self.hold_s, last + RENACK_S) for first, last in self._missing.values())

    def _release(self) -> list[RtpPacket]:
        ready = []
        assert self._expected is not None
        while self._expected in self._held:
            ready.append(self._held.pop(self._expected))
            self._missing.pop(self._expected, None)
            self._expected = (self._expected + 1) & 0xFFFF
        return ready

    def _give_up(self) -> list[RtpPacket]:
        """Skip to the oldest packet held: what is missing before it is lost."""
        assert self._expected is not None
        if not self._held:
            self._missing.clear()
            return []
        expected = self._expected
        oldest = min(self._held, key=lambda s: sequence_after(expected, s))
        for sequence in list(self._missing):
            if sequence_after(oldest, sequence) < 0:
                del self._missing[sequence]
        self._expected = oldest
        return self._release()
