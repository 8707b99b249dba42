"""aiortc's NACKs asked again at the measured round trip, and a picture's lost tail probed for, as the RTP path does.

aiortc's receiver (1.16) asks for the packets missing when a later packet shows a gap (its `NackGenerator`), and
again only when another gap opens: a lost retransmission is waited for until the jitter buffer gives the gap up
(`jitter.GIVE_UP_S`) and costs the pictures until a keyframe; a picture's last packet lost is noticed only when the
next picture's first packet comes, a frame interval later. Here the receiver's generator is the RTP path's schedule,
`netapp.rtp.reorder.Reorder` (its `RttEstimate`, its asks, its tail probe), fed the sequence numbers and marker bits
alone: a gap asked for at once, again after the round trip measured from NACK to retransmission up to MAX_ASKS
times, a picture whose marker has not come TAIL_S after its newest packet probed for; a timer on the receiver's
event loop sends what `Reorder.tick` says is due. aiortc's jitter buffer still holds and releases the packets.

Each NACK is sent twice, AGAIN_S apart (the second for what is still missing then), and aiortc's sender answers
each: at 3 % loss each way about 6 % of single asks fail (the NACK or its retransmission lost), and each failure
waited a retransmission timeout (a round trip and its variation: 100 ms and more) before the ask again, which was
the uplink of WebRTC's slowest frames (docs/benchmarks.md). Two asks both fail about 0.4 % of the time, for one
NACK and one retransmitted packet more per lost packet.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

from netapp.rtp.reorder import Reorder

AGAIN_S = 0.005  # a NACK's second copy: after the first has left (never in the same datagram), well before a reply

SendNack = Callable[[int, list[int]], Awaitable[None]]  # (media SSRC, sequence numbers): RTCRtpReceiver's own
Count = Callable[[int], None]


def _uncounted(_: int) -> None:
    pass


@dataclass(frozen=True)
class Seen:
    """What the schedule reads of a packet (it holds these, not aiortc's packets and their payloads)."""

    sequence: int
    marker: bool


class TimedNacks:
    """Stands in for aiortc's `NackGenerator`: `add(packet)` says whether to NACK `missing` now (aiortc's receiver
    sends them); the asks again and the tail probes go out from a timer through `send`."""

    def __init__(
        self,
        send: SendNack,
        clock: Callable[[], float] = time.monotonic,
        on_nacked: Count = _uncounted,
        on_recovered: Count = _uncounted,
    ) -> None:
        self.reorder = Reorder()
        self.missing: list[int] = []  # asked for by the last `add`
        self._on_nacked, self._on_recovered = on_nacked, on_recovered  # sequence numbers asked for; packets that came
        self._send = send
        self._clock = clock
        self._ssrc: int | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._again: set[asyncio.TimerHandle] = set()  # second copies due
        self._sending: set[asyncio.Task] = set()

    def add(self, packet: Any) -> bool:
        """A packet arrived (aiortc's `RtpPacket`, a retransmission unwrapped): whether `missing` is to be asked."""
        now = self._clock()
        self._ssrc = packet.ssrc
        _, self.missing = self.reorder.push(Seen(packet.sequence_number, bool(packet.marker)), now)
        if self.missing:  # aiortc's receiver sends the first NACK on our word
            self._on_nacked(len(self.missing))
            self._twice(list(self.missing))
        if self.reorder.recovered:
            self._on_recovered(len(self.reorder.recovered))
            self.reorder.recovered.clear()  # the waits (the RTP path's histogram): counted only here
        self._arm(now)
        return bool(self.missing)

    def due(self, now: float) -> list[int]:
        """The sequence numbers to ask for at `now`: asks again and tail probes (gaps waited for too long are
        given up here)."""
        _, asked = self.reorder.tick(now)
        if asked:
            self._on_nacked(len(asked))
        return asked

    def close(self) -> None:
        self._stop_timer()
        for handle in self._again:
            handle.cancel()
        self._again.clear()

    def _stop_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _twice(self, asked: list[int]) -> None:
        """The NACK for `asked` sent again AGAIN_S from now, for those still missing then (see the module)."""
        loop = asyncio.get_running_loop()
        handle: asyncio.TimerHandle | None = None

        def again() -> None:
            self._again.discard(handle)  # type: ignore[arg-type]
            still = [sequence for sequence in asked if self.reorder.is_missing(sequence)]
            if still:
                self._on_nacked(len(still))
                self._nack(still)

        handle = loop.call_later(AGAIN_S, again)
        self._again.add(handle)

    def _nack(self, sequences: list[int]) -> None:
        if self._ssrc is not None:
            task = asyncio.get_running_loop().create_task(self._send(self._ssrc, sequences))
            self._sending.add(task)
            task.add_done_callback(self._sending.discard)

    def _arm(self, now: float) -> None:
        """A timer for the next ask again, give-up or tail probe (`Reorder.next_deadline`)."""
        self._stop_timer()
        deadline = self.reorder.next_deadline()
        if deadline is not None:
            self._timer = asyncio.get_running_loop().call_later(max(0.0, deadline - now), self._tick)

    def _tick(self) -> None:
        self._timer = None
        now = self._clock()
        asked = self.due(now)
        if asked:
            self._nack(asked)
            self._twice(asked)
        self._arm(now)


def asking_receiver() -> type:
    """aiortc's `RTCRtpReceiver` with `TimedNacks` for video (built when aiortc is importable)."""
    from aiortc.rtcrtpreceiver import RTCRtpReceiver

    class AskingReceiver(RTCRtpReceiver):
        on_nacked: Count = _uncounted
        on_recovered: Count = _uncounted

        def __init__(self, kind: str, transport: Any) -> None:
            super().__init__(kind, transport)
            if kind == "video":  # the name aiortc's receiver reads its generator by (audio has none)
                counts = {"on_nacked": type(self).on_nacked, "on_recovered": type(self).on_recovered}
                self._RTCRtpReceiver__nack_generator = TimedNacks(self._send_rtcp_nack, **counts)

        async def stop(self) -> None:
            generator = self._RTCRtpReceiver__nack_generator
            if isinstance(generator, TimedNacks):
                generator.close()
            await super().stop()

    return AskingReceiver


def install(on_nacked: Count = _uncounted, on_recovered: Count = _uncounted) -> None:
    """Make the peer connections of this process receive video with `TimedNacks`, counting into these."""
    import aiortc.rtcpeerconnection

    if getattr(aiortc.rtcpeerconnection.RTCRtpReceiver, "__name__", "") != "AskingReceiver":
        aiortc.rtcpeerconnection.RTCRtpReceiver = asking_receiver()
    receiver = aiortc.rtcpeerconnection.RTCRtpReceiver
    receiver.on_nacked, receiver.on_recovered = staticmethod(on_nacked), staticmethod(on_recovered)
