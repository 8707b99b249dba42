"""Frames through a broker, both ends (docs/broker.md#frames-through-a-broker): the netapp consumes a work queue and
replies to each robot's own address; the robot sends to that queue and reads its replies. One module per broker,
each importing its client library only when used (the `broker` extra)."""

from __future__ import annotations

from netapp.broker.address import AMQP, KAFKA, MQTT, BrokerAddress
from netapp.broker.channel import FrameChannel


def channel_for(address: BrokerAddress) -> FrameChannel:
    """The frames channel that speaks `address`'s protocol (RabbitMQ, MQTT 5 or Kafka)."""
    if address.kind == AMQP:
        from netapp.broker.channels.amqp import AmqpFrames

        return AmqpFrames(address)
    if address.kind == MQTT:
        from netapp.broker.channels.mqtt import MqttFrames

        return MqttFrames(address)
    if address.kind == KAFKA:
        from netapp.broker.channels.kafka import KafkaFrames

        return KafkaFrames(address)
    raise ValueError(f"no frames channel for {address.kind}://")
