"""Kafka through confluent-kafka (librdkafka): an idempotent producer with acks=all, so `publish` returns only once
every in-sync replica has each message, and librdkafka's own retries never duplicate or reorder one
(docs/broker.md#delivery). Keyed by `<netapp>/<source>`: each source's results stay in order on one partition.

librdkafka's producer is thread-based: messages are produced without waiting, then `flush` (on a worker thread,
never the event loop) waits for their delivery reports."""

from __future__ import annotations

import asyncio

from confluent_kafka import KafkaException, Producer

from netapp.broker.address import BrokerAddress
from netapp.broker.backlog import Outgoing
from netapp.broker.link import CONNECT_TIMEOUT_S

DELIVERY_TIMEOUT_S = 10.0  # a batch not delivered within this is failed and sent again after a reconnect


def client_config(address: BrokerAddress) -> dict[str, object]:
    """What every librdkafka client of `address` shares (pure): where the brokers are, and its SASL login."""
    config: dict[str, object] = {
        "bootstrap.servers": ",".join(f"{h}:{p}" for h, p in address.hosts),
        "socket.connection.setup.timeout.ms": int(CONNECT_TIMEOUT_S * 1000),
        "client.id": f"netapp-{address.netapp}",
    }
    if address.username:
        config.update(
            {
                "security.protocol": "SASL_PLAINTEXT",
                "sasl.mechanisms": "PLAIN",
                "sasl.username": address.username,
                "sasl.password": address.password or "",
            }
        )
    return config


def producer_config(address: BrokerAddress) -> dict[str, object]:
    """librdkafka's settings for `address` (pure): at least once without duplicates from its own retries."""
    return {
        **client_config(address),
        "acks": "all",
        "enable.idempotence": True,
        "linger.ms": 1,  # a result waits at most a millisecond for others to share its request
        "message.timeout.ms": int(DELIVERY_TIMEOUT_S * 1000),
    }


class KafkaLink:
    def __init__(self, address: BrokerAddress) -> None:
        self.address = address
        self._producer: Producer | None = None

    async def connect(self) -> None:
        producer = Producer(producer_config(self.address))
        # librdkafka connects lazily: asking for the cluster's metadata proves the broker is there
        await asyncio.to_thread(producer.list_topics, timeout=CONNECT_TIMEOUT_S)
        self._producer = producer

    async def publish(self, batch: list[Outgoing]) -> None:
        producer = self._producer
        if producer is None:
            raise ConnectionError("not connected")
        failures: list[str] = []

        def delivered(error, _message) -> None:  # on the flushing thread
            if error is not None:
                failures.append(str(error))

        for m in batch:
            headers = list(m.headers.items()) if m.headers else None
            producer.produce(m.topic, m.body, key=m.key, headers=headers, on_delivery=delivered)
        left = await asyncio.to_thread(producer.flush, DELIVERY_TIMEOUT_S + 1.0)
        if left or failures:
            raise KafkaException(failures[0] if failures else f"{left} messages not delivered in time")

    async def close(self) -> None:
        producer, self._producer = self._producer, None
        if producer is not None:
            producer.purge()  # what is not delivered is the publisher's again (its batch was restored)
            await asyncio.to_thread(producer.flush, 1.0)
