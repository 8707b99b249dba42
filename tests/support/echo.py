"""A threaded TCP echo server on 127.0.0.1 and its client helpers, for the link emulator's tests."""

from __future__ import annotations

import queue
import socket
import socketserver


class _Handler(socketserver.BaseRequestHandler):
    """First byte picks the behaviour: ``E`` echo until EOF, ``C`` close at once."""

    def handle(self) -> None:
        sock: socket.socket = self.request
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        kind = sock.recv(1)
        if kind == b"E":
            while data := sock.recv(1 << 16):
                sock.sendall(data)
            # EOF seen: the client's close travelled through the relay.
            self.server.eofs.put(True)  # type: ignore[attr-defined]
        sock.close()


class EchoServer(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = False  # port 0: a fresh port, never one another socket holds

    def __init__(self) -> None:
        super().__init__(("127.0.0.1", 0), _Handler)
        self.eofs: queue.Queue[bool] = queue.Queue()

    @property
    def target(self) -> tuple[str, int]:
        host, port = self.server_address[:2]
        return str(host), int(port)


def open_echo(addr: tuple[str, int], kind: bytes = b"E") -> socket.socket:
    """Connect to an :class:`EchoServer` (directly or through a relay) and pick its behaviour."""
    s = socket.create_connection(addr, timeout=15)
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    s.sendall(kind)
    return s


def recv_exact(s: socket.socket, n: int) -> bytes:
    buf = bytearray()
    while len(buf) < n:
        chunk = s.recv(min(1 << 16, n - len(buf)))
        if not chunk:
            raise ConnectionError(f"closed after {len(buf)}/{n} bytes")
        buf += chunk
    return bytes(buf)
