"""MQTT 5 through aiomqtt (over paho-mqtt): QoS 1, so `publish` returns only once the broker has acknowledged each
message (PUBACK); `netapp/NAME/available` is `online` (retained) while connected and `offline` as the connection's
last will, so a reader learns of a netapp that vanished (docs/broker.md#addresses)."""

from __future__ import annotations

import asyncio
import logging
import socket

import aiomqtt

from netapp.broker.address import BrokerAddress
from netapp.broker.backlog import Outgoing
from netapp.broker.link import CONNECT_TIMEOUT_S

QOS = 1
# paho's client, through aiomqtt, warns for every publish past 10 waiting for their PUBACK: a batch does that by design
CLIENT_LOG = logging.getLogger(__name__ + ".client")
CLIENT_LOG.setLevel(logging.ERROR)
ONLINE, OFFLINE = b"online", b"offline"


async def enter(client: aiomqtt.Client) -> None:
    """Connect `client`, with Nagle's algorithm off on its socket (the netapp's and the robot's alike). paho leaves it
    on, so a small message sent while an earlier one is not yet acknowledged (a result after the frame's PUBACK, the
    tail of a 94 KB frame) waits for the peer's delayed ACK: up to 40 ms, measured as +21 ms at 25 FPS."""
    await client.__aenter__()
    sock = client._client.socket()  # paho's own (aiomqtt does not wrap it); an SSL socket takes the option too
    if sock is not None and sock.family in (socket.AF_INET, socket.AF_INET6):
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)


class MqttLink:
    def __init__(self, address: BrokerAddress) -> None:
        self.address = address
        self._client: aiomqtt.Client | None = None

    @property
    def available_topic(self) -> str:
        return self.address.fill("available", "")

    async def connect(self) -> None:
        (host, port), address = self.address.hosts[0], self.address
        client = aiomqtt.Client(
            host,
            port,
            username=address.username,
            password=address.password,
            protocol=aiomqtt.ProtocolVersion.V5,
            will=aiomqtt.Will(self.available_topic, OFFLINE, qos=QOS, retain=True),
            timeout=CONNECT_TIMEOUT_S,
            logger=CLIENT_LOG,
        )
        await enter(client)
        self._client = client
        await client.publish(self.available_topic, ONLINE, qos=QOS, retain=True)

    async def publish(self, batch: list[Outgoing]) -> None:
        if self._client is None:
            raise ConnectionError("not connected")
        client = self._client
        await asyncio.gather(*(client.publish(m.topic, m.body, qos=QOS) for m in batch))

    async def close(self) -> None:
        client, self._client = self._client, None
        if client is None:
            return
        try:  # a clean close sends no will: say it ourselves
            await client.publish(self.available_topic, OFFLINE, qos=QOS, retain=True, timeout=1.0)
        except Exception:  # noqa: BLE001 (the connection may be gone already)
            pass
        try:
            await asyncio.wait_for(client.__aexit__(None, None, None), CONNECT_TIMEOUT_S)
        except Exception:  # noqa: BLE001
            pass
