"""The relay's listening sockets and the connections it accepted: each connection a task on the relay's loop,
every socket closed at shutdown, even one whose task never ran."""

from __future__ import annotations

import asyncio
import logging
import socket
from collections.abc import Callable, Coroutine

log = logging.getLogger("linkemu")

Handler = Callable[[asyncio.StreamReader, asyncio.StreamWriter], Coroutine[object, object, None]]


class Acceptor:
    """Our own accept callbacks rather than asyncio.start_server: on Python 3.11 a connection accepted just as a
    Server closes hits an assertion and leaks its socket. Used on the loop's thread only."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        self._listeners: list[socket.socket] = []
        self._tasks: set[asyncio.Task[None]] = set()
        self._accepted: dict[socket.socket, list[asyncio.StreamWriter | None]] = {}

    def listen(self, listener: socket.socket, handler: Handler) -> None:
        """Run `handler` on each connection `listener` (listening, non-blocking) accepts."""
        self._listeners.append(listener)
        self._loop.add_reader(listener.fileno(), self._on_acceptable, listener, handler)

    def keep(self, task: asyncio.Task[None]) -> None:
        """Cancel `task` at shutdown, as a connection's."""
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def _on_acceptable(self, listener: socket.socket, handler: Handler) -> None:
        # A plain reader callback, not `await sock_accept()`: cancelling a task whose accept
        # already completed would drop the accepted socket on the floor.
        for _ in range(64):  # bounded so one busy listener cannot starve the relay
            try:
                conn, _ = listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:  # e.g. EMFILE: the client sees a refused connection
                log.warning("accept failed: %s", exc)
                return
            conn.setblocking(False)
            # Registered before the task exists: a task cancelled before its first step never
            # runs its own clean-up, so shutdown closes these sockets itself.
            entry: list[asyncio.StreamWriter | None] = [None]
            self._accepted[conn] = entry
            self.keep(self._loop.create_task(self._run_conn(conn, entry, handler)))

    async def _run_conn(self, conn: socket.socket, entry: list[asyncio.StreamWriter | None], handler: Handler) -> None:
        try:
            reader, writer = await asyncio.open_connection(sock=conn)
            entry[0] = writer
            await handler(reader, writer)
        except asyncio.CancelledError:
            pass  # only shutdown cancels; close_accepted releases the socket
        finally:
            if entry[0] is None:
                conn.close()
            else:
                entry[0].transport.abort()  # no-op when the relay already closed it
            self._accepted.pop(conn, None)

    def close_listeners(self) -> None:
        for listener in self._listeners:
            if listener.fileno() != -1:
                self._loop.remove_reader(listener.fileno())
                listener.close()
        self._listeners.clear()

    def close_accepted(self) -> None:
        for conn, (writer,) in list(self._accepted.items()):
            if writer is None:
                conn.close()
            else:
                writer.transport.abort()
        self._accepted.clear()

    async def shutdown(self) -> None:
        """Stop accepting, cancel every connection's task (and the kept ones), close what they left open."""
        self.close_listeners()
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self.close_accepted()
