"""AMQP 0-9-1 (RabbitMQ) through aio-pika: a channel in publisher-confirm mode, so `publish` returns only once the
broker has each message; persistent messages to a durable topic exchange (docs/broker.md#delivery)."""

from __future__ import annotations

import asyncio
import logging

import aio_pika

from netapp.broker.address import BrokerAddress
from netapp.broker.backlog import Outgoing
from netapp.broker.link import CONNECT_TIMEOUT_S
from netapp.broker.message import CONTENT_TYPE

# aiormq logs every failed try (an ERROR a second while a broker restarts) and every close by the broker with its
# traceback: the publisher's and the consumer's `Outage` say each outage once, with how long it lasted
logging.getLogger("aiormq.connection").setLevel(logging.CRITICAL)


async def open_connection(address: BrokerAddress) -> aio_pika.abc.AbstractConnection:
    """A connection to `address`'s RabbitMQ (the frames channel opens its own the same way)."""
    (host, port) = address.hosts[0]
    # aio_pika.connect, not connect_robust: the caller reconnects itself, with its buffer and its log lines
    return await aio_pika.connect(
        host=host,
        port=port,
        login=address.username or "guest",
        password=address.password or "guest",
        virtualhost=address.vhost,
        timeout=CONNECT_TIMEOUT_S,
        client_properties={"connection_name": f"netapp {address.netapp}"},
    )


class AmqpLink:
    def __init__(self, address: BrokerAddress) -> None:
        self.address = address
        self._connection: aio_pika.abc.AbstractConnection | None = None
        self._exchange: aio_pika.abc.AbstractExchange | None = None

    async def connect(self) -> None:
        address = self.address
        self._connection = await open_connection(address)
        channel = await self._connection.channel(publisher_confirms=True)
        self._exchange = await channel.declare_exchange(
            address.addressing["exchange"], aio_pika.ExchangeType.TOPIC, durable=True
        )

    async def publish(self, batch: list[Outgoing]) -> None:
        if self._exchange is None:
            raise ConnectionError("not connected")
        exchange = self._exchange
        await asyncio.gather(
            *(
                exchange.publish(
                    aio_pika.Message(
                        m.body,
                        content_type=CONTENT_TYPE,
                        delivery_mode=aio_pika.DeliveryMode.PERSISTENT,
                        headers=m.headers,
                    ),
                    routing_key=m.topic,
                )
                for m in batch
            )
        )

    async def close(self) -> None:
        connection, self._connection, self._exchange = self._connection, None, None
        if connection is not None:
            try:
                await asyncio.wait_for(connection.close(), CONNECT_TIMEOUT_S)
            except Exception:  # noqa: BLE001 (a connection already gone closes with whatever error)
                pass
