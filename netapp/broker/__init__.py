"""The broker channel (docs/broker.md): results published to RabbitMQ (AMQP 0-9-1), MQTT or Kafka.

Shared by the netapp and the robot, so it imports neither: `address` reads a broker URL, `message` builds the one
message a result becomes, `backlog` bounds what waits while a broker is away, `publisher` sends it at least once over
one of the `links` (each imports its client library only when used: the `broker` extra).
"""
