"""Bounds on what one Socket.IO connection can make the netapp buffer before any handler runs.

A Socket.IO packet announces how many binary attachments follow, and python-socketio keeps every attachment in
memory until the count is reached: a packet announcing 1,000,000 of them, then 250 messages of 8 MB, held 2 GB for
one connection. Here a packet may announce at most `max_attachments`, and hold at most `max_bytes` of them; past
either, the robot gets a `data_error` saying why and the connection is closed (its buffered bytes are freed); so
is a connection that sends a packet python-socketio cannot parse (one log line, not a traceback).
"""

from __future__ import annotations

import logging
from typing import Any

from netapp import wire_json
from netapp.protocol import DATA_ERROR_EVENT, DATA_NAMESPACE, error_event
from netapp.startup import SOCKETIO_CLIENTS, deferred

with deferred(*SOCKETIO_CLIENTS):  # not the server's (netapp.startup)
    import socketio
    from socketio.packet import Packet

log = logging.getLogger(__name__)


class PacketRefused(ValueError):
    """A packet over the attachment limits: its connection is closed."""


def bounded_packet_class(max_attachments: int, max_bytes: int) -> type[Packet]:
    """python-socketio's packet (its `serializer` option) with limits on binary attachments, its JSON by
    `netapp.wire_json`."""

    class BoundedPacket(Packet):
        json = wire_json

        def decode(self, encoded_packet: Any) -> int:
            count = super().decode(encoded_packet)
            if count > max_attachments:
                raise PacketRefused(f"a packet announced {count} binary attachments; at most {max_attachments} allowed")
            return count

        def add_attachment(self, attachment: bytes) -> bool:
            self.buffered = getattr(self, "buffered", 0) + len(attachment)
            if self.buffered > max_bytes:
                self.attachments.clear()
                raise PacketRefused(f"a packet's binary attachments are over {max_bytes} bytes")
            return super().add_attachment(attachment)

    return BoundedPacket


class BoundedAsyncServer(socketio.AsyncServer):
    """An AsyncServer that closes a connection whose packet breaks the limits of `bounded_packet_class`."""

    async def _handle_eio_message(self, eio_sid: str, data: Any) -> None:
        try:
            await super()._handle_eio_message(eio_sid, data)
        except ValueError as exc:  # PacketRefused, or a packet python-socketio cannot parse: one line, no traceback
            self._binary_packet.pop(eio_sid, None)
            log.warning("closing Socket.IO connection %s: %s", eio_sid, exc)
            sid = self.manager.sid_from_eio_sid(eio_sid, DATA_NAMESPACE)
            if sid is not None:
                reason = "packet_refused" if isinstance(exc, PacketRefused) else "malformed_packet"
                error = error_event(None, f"{exc}: the connection is closed", reason)
                await self.emit(DATA_ERROR_EVENT, error, to=sid, namespace=DATA_NAMESPACE)
            await self.eio.disconnect(eio_sid)
