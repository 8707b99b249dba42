"""Packets put back in sequence order before the depacketiser, a gap waited for while it is asked for again (RTCP
generic NACK, RFC 4585): pure, bounded, the time passed in.

A gap is asked for at once, again after a retransmission timeout (the round trip measured from NACK to
retransmission, as TCP does: `RttEstimate`) up to MAX_ASKS times, and waited for up to `hold_s` (those asks' worth);
then it is given up, and the depacketiser sees the jump in sequence numbers (a loss: the pictures until the next
keyframe). A sender that ignores NACKs (GStreamer's `udpsink` alone) costs only that wait on each loss.

A picture's last packet (the one with the marker bit) lost is noticed without waiting for the next picture: the
packets of a picture come in a burst, so when the newest packet has no marker and nothing follows it for `tail_s`,
the next sequence number is asked for (a *tail probe*) and waited for like any gap.

Each packet costs at most MAX_MISSING steps, whatever the gap its sequence number claims: only sequence numbers
never seen before are walked (those after the newest), and a jump past MAX_MISSING starts the stream again there.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from netapp.rtp.packet import RtpPacket, sequence_after

# Before the first NACK was answered (a sender that ignores NACKs never answers one): asked again every 40 ms and
# held 120 ms, three round trips of 40 ms, so such a sender's loss costs no more than that wait.
INITIAL_RENACK_S = 0.04
MIN_RTT_S, MAX_RTT_S = 0.005, 1.0  # what a sample may say: beyond, it is clamped
MAX_ASKS = 3  # NACKs per missing packet: a retransmission lost twice is rare (0.1 % at 3 % loss each way)
MARGIN_S = 0.01  # RFC 6298's G: asked again at least this long after the round trip, however steady it was
TAIL_S = 0.015  # a picture's packets are sent back to back: this long without its marker, its end was lost
MAX_HELD = 512  # packets waiting behind a gap: past it the gap is given up at once
# Sequence numbers asked for at once. A jump past it (a burst that long lost, or a hostile sender's sequence numbers)
# is not asked for: what was waited for is given up and the stream starts again at the packet (the depacketiser sees
# the loss and waits for a keyframe), so a packet's work is bounded whatever its sequence number says.
MAX_MISSING = 128


@dataclass
class RttEstimate:
    """Smoothed round trip and its variation from NACK -> retransmission samples (RFC 6298's estimator)."""

    srtt: float = INITIAL_RENACK_S
    rttvar: float = 0.0
    samples: int = 0

    def add(self, sample: float) -> None:
        sample = min(MAX_RTT_S, max(MIN_RTT_S, sample))
        if self.samples == 0:
            self.srtt, self.rttvar = sample, sample / 2
        else:
            self.rttvar = 0.75 * self.rttvar + 0.25 * abs(self.srtt - sample)
            self.srtt = 0.875 * self.srtt + 0.125 * sample
        self.samples += 1

    @property
    def renack_s(self) -> float:
        """How long a NACK is waited for before the packet is asked for again."""
        if self.samples == 0:
            return INITIAL_RENACK_S
        return min(MAX_RTT_S, self.srtt + max(MARGIN_S, 4 * self.rttvar))

    @property
    def hold_s(self) -> float:
        """How long a gap is waited for in all: every ask's retransmission timeout."""
        return MAX_ASKS * self.renack_s


@dataclass
class Missing:
    first: float  # when it was first asked for
    last: float  # when it was last asked for
    asks: int = 1
    probe: bool = False  # asked for by a tail probe (it may not have been sent)


@dataclass
class Reorder:
    tail_s: float = TAIL_S
    max_held: int = MAX_HELD
    rtt: RttEstimate = field(default_factory=RttEstimate)
    _expected: int | None = None
    _held: dict[int, RtpPacket] = field(default_factory=dict)  # by sequence number
    _missing: dict[int, Missing] = field(default_factory=dict)  # by sequence number
    _newest: int | None = None  # the newest sequence number seen
    _open_since: float | None = None  # when the newest packet came, while it has no marker (its picture is open)
    # What was recovered and given up since the caller last took them (seconds each waited; packets): its metrics
    recovered: list[float] = field(default_factory=list)
    given_up: int = 0
    probes: int = 0
    restarts: int = 0  # jumps past MAX_MISSING (the stream started again there)

    @property
    def hold_s(self) -> float:
        return self.rtt.hold_s

    def is_missing(self, sequence: int) -> bool:
        """Whether `sequence` is asked for and has not come (nor been given up)."""
        return sequence in self._missing

    def push(self, packet: RtpPacket, now: float) -> tuple[list[RtpPacket] | None, list[int]]:
        """(the packets now in order, None for a late or duplicate one; the sequence numbers to ask for now)."""
        if self._expected is None:
            self._expected = packet.sequence
        step = sequence_after(self._expected, packet.sequence)
        if step < 0 or packet.sequence in self._held:
            return None, []
        ready: list[RtpPacket] = []
        start, new = self._unseen_before(packet.sequence)
        if len(self._missing) + new > MAX_MISSING:
            ready = self._restart_at(packet.sequence)
            start, new = packet.sequence, 0
        self._held[packet.sequence] = packet
        filled = self._missing.pop(packet.sequence, None)
        if filled is not None:
            self.recovered.append(now - filled.first)
            if not filled.probe and (filled.asks == 1 or self.rtt.samples == 0):
                # Karn: a sample only from a packet asked for once; but before the first, the time since its first
                # ask (too long if it answered a later one: the next samples correct it). Else a round trip over
                # INITIAL_RENACK_S would never be measured: each gap asked again before its answer can come.
                self.rtt.add(now - (filled.last if filled.asks == 1 else filled.first))
        if self._newest is None or sequence_after(self._newest, packet.sequence) > 0:
            self._newest = packet.sequence
            self._open_since = None if packet.marker else now
        asked = []
        for k in range(new):
            sequence = (start + k) & 0xFFFF
            if sequence not in self._missing:  # a tail probe's may be there already
                self._missing[sequence] = Missing(now, now)
                asked.append(sequence)
        ready += self._release()
        if len(self._held) > self.max_held:
            ready += self._give_up()
        return ready, asked

    def tick(self, now: float) -> tuple[list[RtpPacket], list[int]]:
        """Give up the gaps waited for `hold_s`; the ones to ask for again, and a tail probe when one is due."""
        ready: list[RtpPacket] = []
        hold, renack = self.rtt.hold_s, self.rtt.renack_s
        if any(now - m.first >= hold for m in self._missing.values()):
            ready = self._give_up()
        asked = []
        for sequence, missing in self._missing.items():
            if missing.asks < MAX_ASKS and now - missing.last >= renack:
                missing.last, missing.asks = now, missing.asks + 1
                asked.append(sequence)
        if self._open_since is not None and now - self._open_since >= self.tail_s:
            self._open_since = None  # once: then it is a gap like any other
            assert self._newest is not None
            sequence = (self._newest + 1) & 0xFFFF
            if sequence not in self._missing:
                self._missing[sequence] = Missing(now, now, probe=True)
                self.probes += 1
                asked.append(sequence)
        return ready, asked

    def next_deadline(self) -> float | None:
        """When `tick` has something to do (monotonic seconds), None while nothing is missing or open."""
        hold, renack = self.rtt.hold_s, self.rtt.renack_s
        due = [m.first + hold for m in self._missing.values()]
        due += [m.last + renack for m in self._missing.values() if m.asks < MAX_ASKS]
        if self._open_since is not None:
            due.append(self._open_since + self.tail_s)
        return min(due) if due else None

    def _unseen_before(self, sequence: int) -> tuple[int, int]:
        """(the first sequence number never seen, how many of them come before `sequence`): every one from the
        expected packet up to the newest is held or missing already, so only those after the newest are new."""
        assert self._expected is not None
        start = self._expected
        if self._newest is not None and sequence_after(self._expected, self._newest) >= 0:
            start = (self._newest + 1) & 0xFFFF
        return start, max(0, sequence_after(start, sequence))

    def _restart_at(self, sequence: int) -> list[RtpPacket]:
        """Give up everything missing and start the stream again at `sequence`: what is held goes on, in order."""
        assert self._expected is not None
        expected = self._expected
        ready = [self._held.pop(s) for s in sorted(self._held, key=lambda s: sequence_after(expected, s))]
        self.given_up += len(self._missing)
        self._missing.clear()
        self.restarts += 1
        self._expected = sequence
        return ready

    def _release(self) -> list[RtpPacket]:
        ready = []
        assert self._expected is not None
        while self._expected in self._held:
            ready.append(self._held.pop(self._expected))
            self._expected = (self._expected + 1) & 0xFFFF
        return ready

    def _give_up(self) -> list[RtpPacket]:
        """Skip to the oldest packet held: what is missing before it is lost. With none held (a tail probe not
        answered), skip past what was probed for: it is lost, and a packet of it that comes later is late."""
        assert self._expected is not None
        expected = self._expected
        if not self._held:
            if self._missing:
                newest = max(self._missing, key=lambda s: sequence_after(expected, s))
                self.given_up += len(self._missing)
                self._missing.clear()
                self._expected = (newest + 1) & 0xFFFF
            return []
        oldest = min(self._held, key=lambda s: sequence_after(expected, s))
        for sequence in list(self._missing):
            if sequence_after(oldest, sequence) < 0:
                del self._missing[sequence]
                self.given_up += 1
        self._expected = oldest
        return self._release()
