"""Broker URLs (netapp/broker/address.py): the defaults the issue lists, each overridable; credentials from a file or
a variable; the password in no error, repr or redacted form."""

from __future__ import annotations

import pytest

from netapp.broker.address import DEFAULT_BUFFER, parse_broker_url, topic_part


def test_defaults_per_broker_name_the_netapp_and_the_source():
    amqp = parse_broker_url("amqp://rabbit", "cam-app")
    assert amqp.hosts == (("rabbit", 5672),) and amqp.vhost == "/"
    assert amqp.addressing["exchange"] == "netapp"
    assert amqp.destination("robot-7") == ("results.cam-app.robot-7", None)
    mqtt = parse_broker_url("mqtt://mosquitto:1884", "cam-app")
    assert mqtt.hosts == (("mosquitto", 1884),)
    assert mqtt.destination("gate") == ("netapp/cam-app/gate/results", None)
    assert mqtt.fill("available", "") == "netapp/cam-app/available"
    kafka = parse_broker_url("kafka://k1,k2:9093/", "cam-app")
    assert kafka.hosts == (("k1", 9092), ("k2", 9093))
    assert kafka.destination("gate") == ("netapp.results", "cam-app/gate")
    assert amqp.buffer == DEFAULT_BUFFER


def test_the_netapp_name_comes_from_netapp_id_by_default():
    assert parse_broker_url("mqtt://m", env={"NETAPP_ID": "edge-1"}).netapp == "edge-1"
    assert parse_broker_url("mqtt://m", env={}).netapp == "netapp"


def test_every_address_is_overridable_with_both_placeholders():
    amqp = parse_broker_url("amqp://r/prod?exchange=fleet&routing_key=det.{source}.{netapp}", "n")
    assert amqp.vhost == "prod" and amqp.addressing["exchange"] == "fleet"
    assert amqp.destination("r1") == ("det.r1.n", None)
    kafka = parse_broker_url("kafka://k?topic=lake.{netapp}&key={source}", "n")
    assert kafka.destination("cam") == ("lake.n", "cam")


def test_a_source_never_adds_levels_or_wildcards_to_a_topic():
    assert topic_part("a.b/c+#*d") == "a_b_c___d"
    assert topic_part("") == "_" and len(topic_part("x" * 500)) == 128
    assert parse_broker_url("mqtt://m", "n").destination("+/#")[0] == "netapp/n/___/results"


def test_credentials_from_a_file_or_a_variable(tmp_path):
    secret = tmp_path / "password"
    secret.write_text("s3cret\n")
    address = parse_broker_url(f"amqp://netapp@r?password_file={secret}", "n")
    assert (address.username, address.password) == ("netapp", "s3cret")
    address = parse_broker_url("mqtt://m?username_env=U&password_env=P", "n", env={"U": "bot", "P": "pw"})
    assert (address.username, address.password) == ("bot", "pw")


def test_the_password_is_never_shown():
    address = parse_broker_url("amqp://user:hunter2@rabbit:5673/v?buffer=5", "n")
    assert address.password == "hunter2"
    assert "hunter2" not in address.redacted() and "hunter2" not in repr(address)
    assert address.redacted() == "amqp://user@rabbit:5673/v"
    for bad in (
        "amqp://user:hunter2@rabbit:99999/",
        "amqp://user:hunter2@rabbit/?nope=1",
        "amqp://user:hunter2@rabbit/?password_env=P",
        "amqp://user:hunter2@rabbit/?buffer=-1",
        "amqp://user:hunter2@rabbit/?routing_key={password}",
    ):
        with pytest.raises(ValueError) as error:
            parse_broker_url(bad, "n", env={"P": "x"})
        assert "hunter2" not in str(error.value)


@pytest.mark.parametrize(
    "url, says",
    [
        ("redis://r", "amqp://, mqtt:// or kafka://"),
        ("mqtt://a,b", "one host"),
        ("mqtt://", "needs a host"),
        ("mqtt://m?password_env=MISSING", "not set"),
        ("mqtt://m?password_file=/nonexistent/x", "cannot read"),
        ("kafka://k?buffer_mb=0", "above 0"),
    ],
)
def test_a_wrong_url_is_one_line_that_says_what(url, says):
    with pytest.raises(ValueError, match=says):
        parse_broker_url(url, "n", env={})


def test_buffer_bounds_from_the_url():
    address = parse_broker_url("mqtt://m?buffer=100&buffer_mb=0.5", "n")
    assert (address.buffer, address.buffer_bytes) == (100, 512 * 1024)


def test_a_publish_url_whose_client_library_is_missing_is_refused_with_the_install_line(monkeypatch):
    import importlib.util

    from netapp.server.brokers.args import publish_addresses

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name: None if name == "aiomqtt" else real(name))
    with pytest.raises(ValueError, match=r"--publish mqtt://m:1883/: mqtt:// needs aiomqtt.*netapp-toolkit\[broker\]"):
        publish_addresses(["mqtt://m"], "n")
