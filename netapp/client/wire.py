"""The wire sequencer: frames go on the wire one at a time, in the order their slots were claimed.

The robot's thread and the sender thread both transmit (a frame with a free slot goes at once from `send()`), and
an H.264 stream must never go back in time: each claim takes a ticket, and a frame waits for its ticket's turn.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager


class WireSequencer:
    """Tickets in claim order; `turn(ticket)` holds the wire for one frame, `between_frames()` for a session change."""

    def __init__(self) -> None:
        self._ticket_lock = threading.Lock()  # a leaf lock: tickets are taken under the ledger's lock
        self._claimed = 0
        self._cond = threading.Condition()
        self._serving = 0  # the ticket whose frame goes on the wire next

    def ticket(self) -> int:
        """The next turn on the wire (take it where the frame's slot is claimed, so turns follow claims)."""
        with self._ticket_lock:
            self._claimed += 1
            return self._claimed - 1

    @contextmanager
    def turn(self, ticket: int) -> Iterator[None]:
        """Wait for `ticket`'s turn and hold the wire while its frame is encoded and sent; the next turn follows,
        whatever happened to this frame."""
        with self._cond:
            self._cond.wait_for(lambda: self._serving == ticket)
            try:
                yield
            finally:
                self._serving += 1
                self._cond.notify_all()

    @contextmanager
    def between_frames(self) -> Iterator[None]:
        """Hold the wire between two frames (closing a session, or an encoder, not in the middle of a frame)."""
        with self._cond:
            yield
