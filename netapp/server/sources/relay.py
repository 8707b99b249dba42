"""A camera pulled by another replica, watched here: one WATCH of our own at the replica holding the camera's Lease,
its results told to this replica's watchers (docs/cameras.md#several-replicas).

The holder's address is its identity in the Lease (its --advertise-url, http://POD_IP:PORT in a cluster), which
only the replicas can write (RBAC), never anything a client sends. One relay per camera, whatever the number of
watchers here (at most `watchers.MAX_PER_CAMERA`; each transport bounds what waits for its own watcher). The relay's
WATCH carries `X-Netapp-Forwarded`, so a replica that does not hold the camera either (two replicas reading the
Lease at different moments) refuses it rather than relaying it back: never a loop. It connects again, once a
second at most, whenever the holder changes, refuses, or goes away; it ends when the last watcher here leaves or
this replica takes the camera itself. The protocol is the robot's own, free of I/O (`netapp.frames_session`): this
file is its asyncio I/O, and its wait between connections the one `netapp.reconnect.ReconnectPolicy`.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from typing import Any

from websockets.asyncio.client import connect
from websockets.exceptions import WebSocketException

from netapp.frames_session import Acked, FramesSession, Refused, Results
from netapp.framing import frames_url
from netapp.protocol import FORWARDED_HEADER, SOURCE_FIELD, CommandType
from netapp.reconnect import ReconnectPolicy

log = logging.getLogger(__name__)

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
        policy = ReconnectPolicy(first_s=RETRY_S, max_s=RETRY_S)  # the holder may change any time: look again soon
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
            await asyncio.sleep(policy.next_s())

    async def _relay(self, url: str) -> None:
        headers = {FORWARDED_HEADER: "1", **({"Authorization": f"Bearer {self.token}"} if self.token else {})}
        protocol = FramesSession()
        async with connect(
            frames_url(url),
            additional_headers=headers,
            open_timeout=CONNECT_TIMEOUT_S,
            ssl=self.ssl_for(url),
            **protocol.socket_options(),
        ) as ws:
            await ws.send(protocol.command(CommandType.WATCH, {SOURCE_FIELD: self.name}).text)
            while self.holder() == url:
                try:
                    text = await asyncio.wait_for(ws.recv(), CHECK_S)
                except TimeoutError:
                    continue
                got = protocol.receive(text)
                if isinstance(got, Refused) or (isinstance(got, Acked) and not got.ok):
                    self.counted("refused")  # not (or no longer) its holder: read the Lease again
                    return
                if isinstance(got, Acked):
                    self.connected_to, self._failing = url, False
                    self.counted("connected")
                    log.info("camera %s: relaying it from %s, which pulls it", self.name, url)
                elif isinstance(got, Results):
                    self.tell({**got.data, SOURCE_FIELD: self.name})


async def stop(task: asyncio.Task | None) -> None:
    """Cancel a relay's task and wait for it (its connection closes with it)."""
    if task is not None:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
