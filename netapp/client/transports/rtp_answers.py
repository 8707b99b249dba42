"""Which frames the `rtp` transport has sent and which are answered: its results come twice (a datagram, and on the
WebSocket), and over RTP a result's `timestamp` is the RTP timestamp the netapp saw. Pure and bounded; the transport
holds a lock around it.

- the first copy of a result is delivered, with the frame's own timestamp; the second is not;
- the netapp answers a session's pictures in order on the WebSocket, so when a WebSocket answer comes, the frames sent
  before it that got no answer (on either path) never will (their packets lost, or their pictures skipped until a
  keyframe): they are told as dropped, freeing their slots now rather than at the result timeout. A datagram proves
  nothing of the frames before it (they may still be answered on the WebSocket), so it drops none.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

REMEMBERED = 256  # frames whose RTP timestamp is kept to map their results back
MASK = 0xFFFFFFFF  # an RTP timestamp is 32 bits; the netapp's is unwrapped


@dataclass
class WebSocketAnswer:
    timestamp: int | None  # the frame's own, None when it is not one of ours (a stale one: delivered as it is)
    deliver: bool  # False when its datagram came first
    dropped: list[int]  # frames before it that will never be answered (their own timestamps)


@dataclass
class Answers:
    remembered: int = REMEMBERED
    _frames: OrderedDict[int, list] = field(default_factory=OrderedDict)  # RTP ts -> [own ts, answered by datagram]

    def sent(self, rtp_timestamp: int, timestamp: int) -> None:
        self._frames[rtp_timestamp & MASK] = [timestamp, False]
        while len(self._frames) > self.remembered:
            self._frames.popitem(last=False)

    def clear(self) -> None:
        self._frames.clear()

    def from_datagram(self, rtp_timestamp: int) -> int | None:
        """A result's datagram: its frame's own timestamp to deliver it with, None when not to deliver it."""
        entry = self._frames.get(rtp_timestamp & MASK)
        if entry is None or entry[1]:
            return None
        entry[1] = True
        return entry[0]

    def from_websocket(self, rtp_timestamp: int) -> WebSocketAnswer:
        """A result or error on the WebSocket (see the module)."""
        key = rtp_timestamp & MASK
        if key not in self._frames:
            return WebSocketAnswer(None, True, [])
        dropped = []
        while self._frames:
            sent_key, (timestamp, by_datagram) = self._frames.popitem(last=False)
            if sent_key == key:
                return WebSocketAnswer(timestamp, not by_datagram, dropped)
            if not by_datagram:
                dropped.append(timestamp)
        raise AssertionError("unreachable: the key was there")

    def superseded(self, rtp_timestamp: int) -> int | None:
        """A frame the netapp's queue superseded: its own timestamp (None: not ours), forgotten."""
        entry = self._frames.pop(rtp_timestamp & MASK, None)
        return None if entry is None else entry[0]
