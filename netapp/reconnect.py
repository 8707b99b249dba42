"""The one reconnect policy: how long a client waits before each next try to open a connection again.

Every client that opens a connection again uses it, each with its own numbers: the robot's link to a netapp
(`netapp.client.link`), the `frames` transport after a dropped connection (`netapp.client.transports.frames`),
`netapp watch` behind a Service (`netapp.client.watch`) and the replica relay (`netapp.server.sources.relay`).
Pure: it counts nothing but its own schedule and waits for nothing.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class ReconnectPolicy:
    """The waits before each try: `first_s`, then twice the one before (from at least `floor_s`) up to `max_s`. A
    netapp that said when to come back (a refusal's Retry-After) is taken at its word, up to `retry_after_max_s`
    (None: as it says), and the doubling goes on from there."""

    first_s: float
    max_s: float
    floor_s: float = 0.0  # a first wait of 0 doubles from this, not from nothing
    retry_after_max_s: float | None = None
    _wait_s: float | None = field(default=None, init=False, repr=False)

    def next_s(self, retry_after_s: float | None = None) -> float:
        """The wait before the next try: `first_s` the first time (since `reset`), then after each failed try
        (`retry_after_s`: what its refusal asked for, if anything)."""
        if self._wait_s is None:
            self._wait_s = self.first_s
        elif retry_after_s is not None:
            cap = self.retry_after_max_s
            self._wait_s = retry_after_s if cap is None else min(retry_after_s, cap)
        else:
            self._wait_s = min(2 * max(self._wait_s, self.floor_s), self.max_s)
        return self._wait_s

    def reset(self) -> None:
        """A connection opened: the next outage starts the schedule from `first_s` again."""
        self._wait_s = None
