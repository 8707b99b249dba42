"""A camera pulled by another replica, watched here: one WATCH of our own at the replica holding the camera's Lease,
its results told to this replica's watchers (docs/cameras.md#several-replicas).

The holder's address is its identity in the Lease (its --advertise-url, http://POD_IP:PORT in a cluster), which
only the replicas can write (RBAC), never anything a client sends. One relay per camera, whatever the number of
watchers here (at most `watchers.MAX_PER_CAMERA`; each transport bounds what waits for its own watcher). The relay's
WATCH carries `X-Netapp-Forwarded`, so a replica that does not hold the camera either (two replicas reading the
Lease at different moments) refuses it rather than relaying it back: never a loop. It connects again, once a
second at most, whenever the holder changes, refuses, or goes away; it ends when the last watcher here leaves or
this replica takes the camera itself.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections.abc import Callable
from typing import Any

from websockets.asyncio.client import connect
from websockets.exceptions import WebSocketException

from netapp.framing import ACK_EVENT, REFUSED_EVENT, frames_url, read_event
from netapp.protocol import FORWARDED_HEADER, RESULTS_EVENT, SOURCE_FIELD, CommandType

log = logging.getLogger(__name__)

MAX_MESSAGE_BYTES = 4 * 1024 * 1024  # one result message (masks included) from the holder
CONNECT_TIMEOUT_S = 3.0
RETRY_S = 1.0  # between two connections to holders
CHECK_S = 1.0  # how often a quiet connection checks that its holder is still the Lease's


def holder_url(identity: str | None, me: str) -> str | None:
    """The address to relay from, given a Lease's holderIdentity: an http(s) URL other than our own, else None
    (nobody holds it, we do, or the holder named itself without an address, e.g. its pod's name)."""
    if not identity or identity == me or not identity.startswith(("http://", "https://")) or len(identity) > 2048:
        return None
    return identity


class Relay:
    """Relays camera `name`'s results from whichever replica `holder()` names, until cancelled."""

    def __init__(
        self,
        name: str,
        holder: Callable[[], str | None],
        tell: Callable[[dict[str, Any]], None],
        token: str | None = None,
        ssl_for: Callable[[str], Any] | None = None,
        counted: Callable[[str], None] | None = None,
    ) -> None:
        self.name, self.holder, self.tell, self.token = name, holder, tell, token
        self.ssl_for = ssl_for or (lambda url: None)
        self.counted = counted or (lambda outcome: None)  # connected, refused, lost
        self.connected_to: str | None = None  # the holder it relays from now (None: between connections)
        self._failing = False  # told once per outage, not once per attempt

    async def run(self) -> None:
        while True:
            url = self.holder()
            if url is not None:
                try:
                    await self._relay(url)
                except (OSError, WebSocketException, TimeoutError) as exc:
                    self.counted("lost")
                    if not self._failing:
                        log.warning("camera %s: cannot relay it from %s (%s); trying again", self.name, url, exc)
                        self._failing = True
                finally:
                    self.connected_to = None
            await asyncio.sleep(RETRY_S)

    async def _relay(self, url: str) -> None:
        headers = {FORWARDED_HEADER: "1", **({"Authorization": f"Bearer {self.token}"} if self.token else {})}
        async with connect(
            frames_url(url),
            additional_headers=headers,
            open_timeout=CONNECT_TIMEOUT_S,
            max_size=MAX_MESSAGE_BYTES,
            compression=None,
            ssl=self.ssl_for(url),
        ) as ws:
            await ws.send(json.dumps({"cmd_type": int(CommandType.WATCH), "id": 1, "data": {SOURCE_FIELD: self.name}}))
            while self.holder() == url:
                try:
                    text = await asyncio.wait_for(ws.recv(), CHECK_S)
                except TimeoutError:
                    continue
                got = read_event(text)
                if got is None:
                    continue
                name, message = got
                if name == REFUSED_EVENT or (name == ACK_EVENT and not message.get("ok")):
                    self.counted("refused")  # not (or no longer) its holder: read the Lease again
                    return
                if name == ACK_EVENT:
                    self.connected_to, self._failing = url, False
                    self.counted("connected")
                    log.info("camera %s: relaying it from %s, which pulls it", self.name, url)
                elif name == RESULTS_EVENT and isinstance(message.get("data"), dict):
                    self.tell({**message["data"], SOURCE_FIELD: self.name})


async def stop(task: asyncio.Task | None) -> None:
    """Cancel a relay's task and wait for it (its connection closes with it)."""
    if task is not None:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
