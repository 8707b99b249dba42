"""The UDP ports RTP sessions receive on (`netapp serve --rtp-ports 50000-50099`): parsed, handed out, returned."""

from __future__ import annotations

MAX_PORTS = 1024  # a range's size: one port per RTP session, and sessions are bounded by --max-sessions anyway


def parse_port_range(text: str) -> range:
    """'50000-50099' -> range(50000, 50100); ValueError saying what to write instead."""
    low, sep, high = text.partition("-")
    try:
        first, last = int(low), int(high if sep else low)
    except ValueError:
        raise ValueError(f"--rtp-ports takes FIRST-LAST, e.g. 50000-50099, got {text[:40]!r}") from None
    if not 1024 <= first <= last <= 65535:
        raise ValueError(f"--rtp-ports must lie in 1024-65535 with FIRST <= LAST, got {text[:40]!r}")
    if last - first + 1 > MAX_PORTS:
        raise ValueError(f"--rtp-ports names {last - first + 1} ports, over {MAX_PORTS}: name fewer")
    return range(first, last + 1)


class PortPool:
    """Free ports of the range, lowest first; a port is returned when its session closes."""

    def __init__(self, ports: range) -> None:
        self.ports = ports
        self._free = list(reversed(ports))
        self._used: set[int] = set()

    def candidates(self) -> list[int]:
        """The free ports to try, lowest first (the caller binds one and calls `hold`)."""
        return list(reversed(self._free))

    def hold(self, port: int) -> None:
        self._free.remove(port)
        self._used.add(port)

    def give_back(self, port: int) -> None:
        if port in self._used:
            self._used.remove(port)
            self._free.append(port)
            self._free.sort(reverse=True)

    @property
    def free(self) -> int:
        return len(self._free)
