"""Moving the netapp in use to another URL: break before make (`switch_url`, an edge switchover) or make before break
(`move_to`, a switchover the middleware asks for), and closing the netapp a move left behind."""

from __future__ import annotations

import logging
import threading
import time

from netapp.client.assembly import ClientParts
from netapp.client.errors import NetAppError
from netapp.client.link import RECONNECT_INTERVAL_S
from netapp.client.urls import http_url

log = logging.getLogger(__name__)


class Moves:
    """The client's moves, over its parts (the links, the policy's `Switcher`, the ledger)."""

    def __init__(self, parts: ClientParts, result_timeout_s: float) -> None:
        self._parts = parts
        self._result_timeout_s = result_timeout_s

    def in_use(self) -> int:
        """The netapp in use: the first one frames go to (else the policy's first)."""
        mode = self._parts.switcher.mode
        return mode.netapps[0] if mode.netapps else self._parts.policy.first

    def switch_url(self, url: str) -> None:
        """Break before make: the netapp in use moves to `url`; its frames in flight are counted lost."""
        url = http_url(url)
        link = self._parts.links[self.in_use()]
        if url != link.url:
            link.switch(url)

    def move_to(self, url: str) -> None:
        """Make before break: a session opens at `url` first (a stateful netapp's state restored in it), every
        frame goes to both until the new one has answered on time a few times in a row (`netapp.client.policy`,
        moves), then the old one is closed once none of its frames is still in flight. No frame is lost to the
        move."""
        parts, url = self._parts, http_url(url)
        links, health, old = parts.links, parts.policy.health, self.in_use()
        if any(link.url == url for i, link in enumerate(links) if not health[i].retired):
            return  # there already (or moving there)
        # A netapp a previous move left behind is closed by now: its place takes the new one (at most one spare).
        spare = next((i for i, h in enumerate(health) if h.retired and not h.up), None)
        now = time.monotonic_ns()
        if spare is None:
            link = parts.new_link(len(links), url)
            links.append(link)
            parts.switcher.add()
        else:
            link = links[spare]
        parts.switcher.begin_move(old, link.index, now)
        log.info("moving %s -> %s (make before break)", links[old].url, url)
        try:
            if spare is None:
                link.open()
            else:
                link.switch(url)
        except NetAppError as exc:  # the old one serves on; the move ends by its timeout
            parts.receiver.outage(link, f"{exc}; trying again every {RECONNECT_INTERVAL_S:g} s", "unreachable")
            link.reconnect_in_background()
            return
        if parts.ledger.wait_idle(0.0):  # no frame on its way: nothing to hedge, the old one may go now
            parts.switcher.finish_move(f"moved to {url}")

    def retire(self, index: int) -> None:
        """A move left this netapp behind: close it once its frames in flight are answered (or lost)."""

        def close() -> None:
            self._parts.ledger.wait_clear(index, self._result_timeout_s)
            self._parts.links[index].close()

        threading.Thread(target=close, name="netapp-retire", daemon=True).start()
