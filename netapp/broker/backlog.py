"""What waits to be published, bounded in count and in bytes (pure: no I/O, no clock).

Messages leave in batches (`take`) and are forgotten only once the broker confirmed them (`confirm`); a batch the
broker did not confirm goes back to the front (`restore`), in order, to be sent again: at least once. While the broker
is away the backlog fills; past either bound the oldest waiting message gives way to the newest (as a robot's own
queue does), and each one lost is counted by why: `count` (the `buffer=` bound), `bytes` (`buffer_mb=`), or
`too_large` (one message bigger than the whole byte bound, never kept).
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Outgoing:
    """One message on its way: where it goes (topic or routing key), its key (Kafka's; None elsewhere), its body."""

    topic: str
    body: bytes
    key: str | None = None
    # a broker's own per-message fields (AMQP reply_to / correlation_id, MQTT 5 properties); None: none
    headers: dict[str, str] | None = None

    @property
    def size(self) -> int:
        return len(self.body)


class Backlog:
    """Bounded FIFO of `Outgoing` messages, with one batch at a time in flight (counted against the bounds too)."""

    def __init__(self, max_count: int, max_bytes: int) -> None:
        self.max_count = max_count
        self.max_bytes = max_bytes
        self._waiting: deque[Outgoing] = deque()
        self._in_flight: list[Outgoing] = []
        self.bytes = 0  # of waiting and in-flight messages
        self.dropped: Counter[str] = Counter()  # reason -> messages lost

    def __len__(self) -> int:
        return len(self._waiting) + len(self._in_flight)

    @property
    def waiting(self) -> int:
        return len(self._waiting)

    def offer(self, message: Outgoing) -> list[str]:
        """Keep `message`; the reasons of the messages this cost (the oldest waiting ones, or itself), one each."""
        if message.size > self.max_bytes:
            self.dropped["too_large"] += 1
            return ["too_large"]
        lost = []
        while self._waiting and (len(self) >= self.max_count or self.bytes + message.size > self.max_bytes):
            reason = "count" if len(self) >= self.max_count else "bytes"
            self.bytes -= self._waiting.popleft().size
            lost.append(reason)
        if len(self) >= self.max_count or self.bytes + message.size > self.max_bytes:
            lost.append("count" if len(self) >= self.max_count else "bytes")  # only the batch in flight is left
            self.dropped.update(lost)
            return lost
        self._waiting.append(message)
        self.bytes += message.size
        self.dropped.update(lost)
        return lost

    def take(self, max_count: int, max_bytes: int) -> list[Outgoing]:
        """The next batch (at least one message when any waits, at most `max_count` and about `max_bytes`), now in
        flight until `confirm` or `restore`."""
        assert not self._in_flight, "one batch in flight at a time"
        size = 0
        while self._waiting and len(self._in_flight) < max_count and (not self._in_flight or size < max_bytes):
            message = self._waiting.popleft()
            size += message.size
            self._in_flight.append(message)
        return list(self._in_flight)

    def confirm(self) -> None:
        """The broker has the batch in flight: forget it."""
        self.bytes -= sum(m.size for m in self._in_flight)
        self._in_flight = []

    def restore(self) -> None:
        """The batch in flight was not confirmed: back to the front, in order, to be sent again."""
        self._waiting.extendleft(reversed(self._in_flight))
        self._in_flight = []
