"""Real brokers for the broker channel's tests, one of each per test session, on free loopback ports
(tests/support/brokers.py); each skips with its install hint where its package is absent. Kafka is librdkafka's mock
cluster (a test double of the protocol, not Kafka) unless KAFKA_BOOTSTRAP names a real broker."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.support.brokers import KafkaMock, Mosquitto, RabbitMQ, kafka_bootstrap


def installed(make):
    """`make()`, or the test skipped with the install line where its package is absent."""
    try:
        return make()
    except FileNotFoundError as exc:
        pytest.skip(str(exc))


@pytest.fixture(scope="session")
def rabbitmq() -> Iterator[RabbitMQ]:
    with installed(RabbitMQ) as broker:
        yield broker


@pytest.fixture(scope="session")
def mosquitto() -> Iterator[Mosquitto]:
    with installed(Mosquitto) as broker:
        yield broker


@pytest.fixture(scope="session")
def kafka_url() -> Iterator[str]:
    """kafka://HOST:PORT/ of a real Kafka (KAFKA_BOOTSTRAP), else of librdkafka's mock cluster."""
    real = kafka_bootstrap()
    if real:
        yield f"kafka://{real}/"
        return
    with installed(KafkaMock) as mock:
        yield mock.url


@pytest.fixture(params=["amqp", "mqtt", "kafka"])
def broker_url(request) -> str:
    """A frames channel's broker, each in turn: RabbitMQ, Mosquitto, and Kafka (librdkafka's mock cluster, a test
    double, unless KAFKA_BOOTSTRAP names a real one). A test module may narrow it with a fixture of its own."""
    if request.param == "amqp":
        return request.getfixturevalue("rabbitmq").url
    if request.param == "kafka":
        pytest.importorskip("confluent_kafka")
        return request.getfixturevalue("kafka_url")
    return f"mqtt://127.0.0.1:{request.getfixturevalue('mosquitto').port}/"
