"""A camera's watchers (connections that sent WATCH), bounded: at most MAX_PER_CAMERA on a camera, at most
MAX_PER_ADDRESS from one address over every camera, and a watcher that reads nothing is let go (pure).

A watcher's transport drops a result it cannot send without waiting (the robot reads nothing: `FramesWire.tell`, the
Socket.IO handlers' watchers) and says so (its `Tell` returns False). A watcher whose results have all been dropped
for STALL_S is dropped: its slot goes to another, and it is told nothing more.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from netapp.server.connection import Tell
from netapp.server.errors import RequestRefused

MAX_PER_CAMERA = 16
MAX_PER_ADDRESS = 4  # over every camera: one machine's `netapp watch` of each of a few cameras
STALL_S = 10.0  # a watcher whose every result was dropped this long is let go
# Why a WATCH was refused, or a watcher let go (`netapp_source_watchers_refused{reason}`)
TOO_MANY_SUBSCRIBERS = "too_many_subscribers"
TOO_MANY_WATCHERS = "too_many_watchers"
STALLED = "stalled"
REASONS = (TOO_MANY_SUBSCRIBERS, TOO_MANY_WATCHERS, STALLED)


@dataclass
class Watcher:
    host: str  # the address it reached us at
    forwarded: bool  # another replica's relay (one per camera there, for all its watchers): no address's share
    taken_at: float  # when it last took a result, or subscribed


def refusal(name: str, camera: dict[Tell, Watcher], everyone: Iterable[Watcher], host: str) -> RequestRefused | None:
    """Why a new watcher from `host` cannot watch camera `name` (its watchers `camera`; `everyone`: every camera's),
    or None."""
    if len(camera) >= MAX_PER_CAMERA:
        message = f"camera {name} has {MAX_PER_CAMERA} subscribers already: try again when one leaves"
        return RequestRefused(TOO_MANY_SUBSCRIBERS, message, 503, retry_after_s=5)
    if sum(1 for w in everyone if w.host == host and not w.forwarded) >= MAX_PER_ADDRESS:
        message = f"{host} watches {MAX_PER_ADDRESS} cameras already (each WATCH counts): close one first"
        return RequestRefused(TOO_MANY_WATCHERS, message, 429, retry_after_s=5)
    return None


def tell_all(watchers: dict[Tell, Watcher], message: dict[str, Any], now: float) -> list[Tell]:
    """Tell each watcher `message`; the watchers that took nothing for STALL_S (to be let go)."""
    stalled = []
    for tell, watcher in list(watchers.items()):
        if tell(message) is not False:  # None: a Tell that cannot drop (a test's list.append)
            watcher.taken_at = now
        elif now - watcher.taken_at >= STALL_S:
            stalled.append(tell)
    return stalled
