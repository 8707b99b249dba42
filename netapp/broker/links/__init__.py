"""One link per broker (`netapp.broker.link.BrokerLink`), each in its module, each importing its client library only
when it is made (the `broker` extra)."""

from __future__ import annotations

import importlib.util

from netapp.broker.address import AMQP, KAFKA, MQTT, BrokerAddress
from netapp.broker.link import BrokerLink

CLIENT_MODULES = {AMQP: "aio_pika", MQTT: "aiomqtt", KAFKA: "confluent_kafka"}
INSTALL_HINT = "pip install 'netapp-toolkit[broker]'"


def missing_client(kind: str) -> str | None:
    """Why `kind`'s link cannot be made here (its client library is not installed), as one line; None: it can."""
    module = CLIENT_MODULES[kind]
    if importlib.util.find_spec(module) is None:
        return f"{kind}:// needs {module}, which is not installed: {INSTALL_HINT}"
    return None


def link_for(address: BrokerAddress) -> BrokerLink:
    """The link that speaks `address`'s protocol."""
    if address.kind == AMQP:
        from netapp.broker.links.amqp import AmqpLink

        return AmqpLink(address)
    if address.kind == MQTT:
        from netapp.broker.links.mqtt import MqttLink

        return MqttLink(address)
    if address.kind == KAFKA:
        from netapp.broker.links.kafka import KafkaLink

        return KafkaLink(address)
    raise ValueError(f"no link for {address.kind}://")
