"""Putting frames on a WebSocket without making the robot's thread wait on the link.

`send()` runs on the robot's thread (`netapp.client.sender`): it must never wait for the network. A frame that fits in
what the socket's send buffer has free goes at once from that thread (no hand-off: the common case, a link that
keeps up); otherwise it is queued for the connection's writer thread, which waits on the link instead, and every
frame after it goes the same way until the queue is empty, so the order holds. The client's in-flight bound keeps
that queue to a frame or two.
"""

from __future__ import annotations

import socket
import struct
import threading
from collections import deque

from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection

try:  # the bytes a socket has not sent yet: Linux (SIOCOUTQ); elsewhere every frame goes by the writer thread
    import fcntl
    import termios

    OUTQ: int | None = termios.TIOCOUTQ
except (ImportError, AttributeError):
    OUTQ = None


def has_room(sock: socket.socket, size: int) -> bool:
    """Whether `size` more bytes fit in the socket's send buffer now, so a send returns without waiting on the link."""
    if OUTQ is None:
        return False
    try:
        queued = struct.unpack("i", fcntl.ioctl(sock.fileno(), OUTQ, b"\0\0\0\0"))[0]
        room = sock.getsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF)
    except (OSError, ValueError):
        return False
    return queued + 2 * size <= room  # twice: the kernel counts its own bookkeeping against the buffer too


class Outbox:
    """One connection's outgoing binary messages, in order (see the module)."""

    def __init__(self, ws: ClientConnection) -> None:
        self._ws = ws
        self._queue: deque[bytes] = deque()
        self._cond = threading.Condition()
        self._writing = False  # the writer thread is sending one
        self._failed: ConnectionClosed | None = None
        self._closed = False
        threading.Thread(target=self._write, name="netapp-frames-writer", daemon=True).start()

    def send(self, data: bytes) -> None:
        """Send `data` now if it fits, else queue it; ConnectionClosed once the connection has failed."""
        with self._cond:
            if self._failed is not None:
                raise self._failed
            if not self._queue and not self._writing and has_room(self._ws.socket, len(data)):
                self._ws.send(data)
                return
            self._queue.append(data)
            self._cond.notify()

    def close(self) -> bool:
        """Stop sending (queued frames are dropped); whether a frame is still being written to the link."""
        with self._cond:
            self._closed = True
            self._queue.clear()
            self._cond.notify()
            return self._writing

    def _write(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._queue or self._closed)
                if self._closed:
                    return
                data = self._queue.popleft()
                self._writing = True
            try:
                self._ws.send(data)
            except ConnectionClosed as exc:
                with self._cond:
                    self._failed, self._writing = exc, False
                    self._queue.clear()
                return
            with self._cond:
                self._writing = False
