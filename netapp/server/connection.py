"""One robot's (or camera's) connection to the netapp, whatever carries it: the one session record of every transport.

What every transport's connection has in common lives here: its session (once INIT, `/register`, an offer or the
camera's start opened it), who it is (the priority class and token it connected with, the address it reached us at),
its decoders, where what becomes of its frames goes (its `sink`), how a camera's results reach it (`tell`, WATCH)
and what it holds beside them (an RTP port, a peer connection, a subscription). Each transport keeps only its wire's
own part (`wire`): the Socket.IO /data sid, the `frames` writer (`netapp.server.frames.connection.FramesWire`), the
WebRTC peer connection (`netapp.server.webrtc.peers.Peer`), the camera's reader (`netapp.server.sources.hub.Camera`).
An RTP stream is held by the connection whose INIT (or `/register`) asked for it.

There is one close: `DataPlane.disconnect` when the wire goes away, `DataPlane.close_session` when the session ends
first (idle, unregistered, shutting down); both release what the connection holds, once.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from netapp.server.decoding.decoder import FrameDecoder
from netapp.server.pipeline.frame import ResultSink
from netapp.server.sessions import Session

log = logging.getLogger(__name__)

# Pushes one result message to a connection without waiting (a camera's result, for a connection that WATCHes it);
# its transport bounds what waits for a robot that does not read, and says False for a message it dropped for it.
Tell = Callable[[dict[str, Any]], bool | None]
Release = Callable[[], None]


@dataclass(eq=False)
class Connection:
    """One connection's common part; `key` is its session's id (Socket.IO: the Engine.IO sid; frames: a new id)."""

    key: str
    transport: str  # the `transport` label of the session it opens and of its commands
    sink: ResultSink | None = None  # where its frames' results and errors go (None: kept for polling)
    wire: Any = None  # the transport's own part of it
    granted: int | None = None  # the highest priority class its token grants (None: the netapp's default)
    token: str | None = None  # what it connected with: a WATCH relayed from another replica shows it there
    host: str = "127.0.0.1"  # the address it reached us at: where its RTP goes, if it asks for RTP
    forwarded: bool = False  # another replica's relay (X-Netapp-Forwarded): its WATCH is never relayed again
    tell: Tell | None = None  # how a camera's results reach it (None: it cannot WATCH)
    # True where the wire stays open after its session ends (Socket.IO, frames: another INIT may follow); else the
    # connection ends with its session (HTTP, WebRTC, a camera)
    outlives_session: bool = False
    session: Session | None = None
    decoders: dict[str, FrameDecoder] = field(default_factory=dict)  # by codec or event, opened on its first frame
    closed: bool = False
    _holds: list[Release] = field(default_factory=list)  # released when its session ends (or it closes)
    _closers: list[Release] = field(default_factory=list)  # released when it closes
    client: str = ""  # the address it came from: a few camera watchers per address (`sources.watchers`)

    @property
    def live_session(self) -> Session | None:
        """Its session while open."""
        return self.session if self.session is not None and not self.session.closed else None

    def decoder(self, name: str, open_decoder: Callable[[], FrameDecoder]) -> FrameDecoder:
        """Its decoder for `name` (a codec, a Socket.IO event), opened on first use: one per connection, as video
        decoders keep state between frames."""
        decoder = self.decoders.get(name)
        if decoder is None:
            decoder = self.decoders[name] = open_decoder()
        return decoder

    def reset_decoders(self) -> None:
        """RESET_STATE: its video streams start again at a keyframe."""
        for decoder in self.decoders.values():
            decoder.reset()

    def hold(self, release: Release) -> None:
        """`release` runs when its session ends, or it closes, whichever comes first (an RTP port, a peer)."""
        self._holds.append(release)

    def on_close(self, release: Release) -> None:
        """`release` runs when it closes (a camera subscription: WATCH opens no session)."""
        self._closers.append(release)

    def end_session(self) -> None:
        """Its session ended: what it held for it goes (it may open another, where it `outlives_session`)."""
        holds, self._holds = self._holds, []
        _release_all(holds, self.key)
        if not self.outlives_session:
            self.close()

    def close(self) -> None:
        """Release everything it holds, once: its session's holds, its decoders, its subscriptions, its wire."""
        if self.closed:
            return
        self.closed = True
        holds, self._holds = self._holds, []
        closers, self._closers = self._closers, []
        decoders = [decoder.close for decoder in self.decoders.values()]
        self.decoders.clear()
        _release_all([*holds, *decoders, *closers], self.key)


def _release_all(releases: list[Release], key: str) -> None:
    """Run each release, later ones even when one fails (a port must go back whatever a decoder does)."""
    for release in releases:
        try:
            release()
        except Exception:
            log.exception("connection %s: releasing what it held failed", key)
