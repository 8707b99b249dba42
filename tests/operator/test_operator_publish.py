"""A NetApp's `spec.publish` (operator/netapp_operator/publish.py): each broker as `--publish` in the netapp's args,
its password from the Secret in the environment (never the args, never the URL); what is wrong, one sentence; the
CRD's schema."""

from __future__ import annotations

import jsonschema
import pytest
from netapp_operator.spec import parse

from netapp.broker.address import parse_broker_url
from tests.operator.test_operator_render import kinds, netapp, pool, render
from tests.operator.test_operator_rtp import NETAPP_SCHEMA


def container(publish: list) -> dict:
    made = kinds(render(netapp(publish=publish), pool()))
    return made["Deployment"]["spec"]["template"]["spec"]["containers"][0]


def test_brokers_reach_the_args_and_passwords_the_environment():
    made = container([{"url": "amqp://netapp@rabbit.messaging/", "secret": "rabbit"}, {"url": "mqtt://mosquitto/"}])
    args = made["args"]
    urls = [args[i + 1] for i, a in enumerate(args) if a == "--publish"]
    assert urls == ["amqp://netapp@rabbit.messaging/?password_env=NETAPP_PUBLISH_PASSWORD_0", "mqtt://mosquitto/"]
    env = {e["name"]: e.get("valueFrom") for e in made["env"]}
    assert env["NETAPP_PUBLISH_PASSWORD_0"] == {"secretKeyRef": {"name": "rabbit", "key": "password"}}
    assert "NETAPP_PUBLISH_PASSWORD_1" not in env
    # what the netapp makes of it: the user from the URL, the password from the variable the Secret fills
    address = parse_broker_url(urls[0], "n", env={"NETAPP_PUBLISH_PASSWORD_0": "s3cret"})
    assert (address.username, address.password) == ("netapp", "s3cret")


def test_without_publish_no_broker_is_named():
    made = kinds(render(netapp(), pool()))["Deployment"]["spec"]["template"]["spec"]["containers"][0]
    assert "--publish" not in made["args"]


@pytest.mark.parametrize(
    ("publish", "says"),
    [
        ([{"url": "amqp://netapp:hunter2@rabbit/"}], "holds a password: put it in a Secret"),
        ([{"url": "redis://r/"}], "amqp://, mqtt:// or kafka://"),
        ([{"url": "mqtt://m/?nope=1"}], "unknown option nope"),
        ([{"url": "mqtt://m/", "secret": ""}], "must name a Secret"),
        ([{"secret": "s"}], "url must be a broker URL"),
        ([{"url": "mqtt://m/"}] * 9, "at most 8"),
    ],
)
def test_what_is_wrong_is_one_sentence(publish, says):
    problems = [p for p in parse({"image": "i", "publish": publish}).problems if "publish" in p]
    assert len(problems) == 1 and says in problems[0] and "hunter2" not in problems[0], problems


def test_the_crd_takes_brokers_and_refuses_other_schemes():
    spec = NETAPP_SCHEMA["schema"]["openAPIV3Schema"]["properties"]["spec"]
    jsonschema.validate({"image": "i", "publish": [{"url": "kafka://k1:9092,k2:9092/", "secret": "lake"}]}, spec)
    for bad in ([{"url": "http://x/"}], [{"secret": "s"}], [{"url": "mqtt://m/"}] * 9):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate({"image": "i", "publish": bad}, spec)


def test_consume_renders_as_publish_does_with_its_own_variables():
    """spec.consume (frames from a broker's work queue): `--consume`, the password from the Secret in a variable of
    its own; the CRD takes it; what is wrong names spec.consume."""
    made = kinds(render(netapp(consume=[{"url": "kafka://netapp@k:9092/?netapp=n", "secret": "lake"}]), pool()))
    container = made["Deployment"]["spec"]["template"]["spec"]["containers"][0]
    args = container["args"]
    assert args[args.index("--consume") + 1] == "kafka://netapp@k:9092/?netapp=n&password_env=NETAPP_CONSUME_PASSWORD_0"
    env = {e["name"]: e.get("valueFrom") for e in container["env"]}
    assert env["NETAPP_CONSUME_PASSWORD_0"] == {"secretKeyRef": {"name": "lake", "key": "password"}}
    spec = NETAPP_SCHEMA["schema"]["openAPIV3Schema"]["properties"]["spec"]
    jsonschema.validate({"image": "i", "consume": [{"url": "amqp://rabbit/", "secret": "s"}]}, spec)
    problems = parse({"image": "i", "consume": [{"url": "amqp://n:hunter2@r/"}]}).problems
    assert any(p.startswith("spec.consume[0].url holds a password") for p in problems)
