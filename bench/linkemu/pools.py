"""A link per pool: every netapp of a pool is reached through an emulated link of that pool's own, whose figures
change on the pool's schedule (one clock for all pools), so pools on one machine differ as a robot's route to them
does.

    links = PoolLinks({"pool-a": (profile_a, schedule_a), "pool-b": (profile_b, schedule_b)})
    backend = LocalBackend(model=..., url_for=links.url_for)  # the middleware hands robots the links' URLs
    links.start_schedules()  # every pool's schedule from now on (netapps made later join the same clock)
    ...
    links.close()

A pool without an entry is reached directly. The relays run in userspace (no root needed).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Mapping
from urllib.parse import urlsplit

from .emulator import LinkEmulator
from .profiles import LinkProfile
from .schedule import LinkSchedule

log = logging.getLogger("linkemu")


class PoolLinks:
    """Emulated links in front of each pool's netapps; `url_for` is `LocalBackend`'s hook (see the module)."""

    def __init__(self, pools: Mapping[str, tuple[LinkProfile, LinkSchedule]], *, seed: int | None = None) -> None:
        self.pools = dict(pools)
        self.seed = seed
        self.started_at: float | None = None  # time.monotonic() of the schedules' start
        self.links: dict[str, LinkEmulator] = {}  # netapp URL -> its link
        self._lock = threading.Lock()

    def url_for(self, pool: str, url: str) -> str:
        """The URL a robot reaches the netapp at `url` of `pool` by: through the pool's link (made once per URL)."""
        if pool not in self.pools:
            return url
        with self._lock:
            link = self.links.get(url)
            if link is None:
                parts = urlsplit(url)
                profile, schedule = self.pools[pool]
                link = LinkEmulator(
                    profile,
                    (parts.hostname or "127.0.0.1", parts.port or 80),
                    mode="userspace",
                    seed=self.seed,
                    schedule=schedule,
                    hold_schedule=True,
                )
                link.start()
                if self.started_at is not None:
                    link.start_schedule(self.started_at)
                self.links[url] = link
                log.info("pool %s: %s behind a link of its own", pool, url)
        host, port = link.address or ("127.0.0.1", 0)
        return f"{urlsplit(url).scheme}://{host}:{port}"

    def start_schedules(self, at: float | None = None) -> float:
        """Start every pool's schedule at `at` (time.monotonic(); default now), links made later included."""
        with self._lock:
            self.started_at = time.monotonic() if at is None else at
            for link in self.links.values():
                link.start_schedule(self.started_at)
        return self.started_at

    def delay_ms(self, pool: str, t: float) -> float:
        """The one-way delay of `pool`'s link `t` seconds into the schedule (0 for a pool reached directly)."""
        if pool not in self.pools:
            return 0.0
        profile, schedule = self.pools[pool]
        return schedule.profile_at(profile, t).delay_ms

    def close(self) -> None:
        with self._lock:
            links, self.links = list(self.links.values()), {}
        for link in links:
            link.stop()
