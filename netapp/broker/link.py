"""What a broker link is: connect, publish a batch and return only once the broker has confirmed every message of it
(else raise), close. The publisher (`netapp.broker.publisher`) owns the buffer and the reconnecting; a link
(`netapp.broker.links`) only speaks its protocol."""

from __future__ import annotations

from typing import Protocol

from netapp.broker.backlog import Outgoing

CONNECT_TIMEOUT_S = 5.0


class BrokerLink(Protocol):
    async def connect(self) -> None:
        """Open the connection (raises when the broker cannot be reached within CONNECT_TIMEOUT_S)."""
        ...

    async def publish(self, batch: list[Outgoing]) -> None:
        """Send `batch`; returns once the broker confirmed every message (AMQP publisher confirms, MQTT PUBACK,
        Kafka's acks=all), raises otherwise."""
        ...

    async def close(self) -> None:
        """Close the connection (never raises)."""
        ...
