"""Cameras that fail, on loopback, for tests and benchmarks: one that says nothing or nonsense, one that answers
every RTSP request 401 Unauthorized (a camera given the wrong password)."""

from __future__ import annotations

import contextlib
import socket
import threading


def close_listener(server: socket.socket) -> None:
    """Stop listening for good. close() alone leaves a thread blocked in accept() holding the socket, which then
    listens on (and answers a later test's connection to) its port; shutdown() wakes that accept()."""
    with contextlib.suppress(OSError):
        server.shutdown(socket.SHUT_RDWR)
    server.close()


class HostileCamera:
    """A TCP listener on loopback that accepts RTSP connections and then says nothing, or `reply` (nonsense)."""

    def __init__(self, reply: bytes = b"") -> None:
        self.reply = reply
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.accepted: list[socket.socket] = []
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.server.accept()
            except OSError:  # closed
                return
            self.accepted.append(conn)
            if self.reply:
                with contextlib.suppress(OSError):
                    conn.sendall(self.reply)

    def close(self) -> None:
        close_listener(self.server)
        for conn in self.accepted:
            conn.close()


UNAUTHORIZED = b'RTSP/1.0 401 Unauthorized\r\n%s\r\nWWW-Authenticate: Basic realm="cam"\r\n\r\n'


class RefusingCamera:
    """Answers each RTSP request 401 Unauthorized, as a camera given the wrong password does."""

    def __init__(self) -> None:
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.server.accept()
            except OSError:
                return
            threading.Thread(target=self._answer, args=(conn,), daemon=True).start()

    @staticmethod
    def _answer(conn: socket.socket) -> None:
        with conn, contextlib.suppress(OSError):
            while request := conn.recv(4096):
                cseq = next((line for line in request.split(b"\r\n") if line.lower().startswith(b"cseq")), b"CSeq: 1")
                conn.sendall(UNAUTHORIZED % cseq)

    def close(self) -> None:
        close_listener(self.server)
