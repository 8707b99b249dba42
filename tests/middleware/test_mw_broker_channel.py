"""An app whose channel is a broker (operator/netapp_middleware/channel.py, docs/broker.md#from-the-middleware): the
catalogue's `channel` checked (never a password, in either URL), its NetApp told to consume there (`spec.consume`,
named after the NetApp), and the robot handed the broker URL naming its NetApp, which `NetAppClient` takes as it is:
on the local backend with real netapp processes, and on the Kubernetes backend against the API emulator with the
test's kubelet serving the NetApp's own spec. The broker is Kafka: librdkafka's mock cluster (confluent-kafka's
`test.mock.num.brokers`, a test double of the protocol on a real loopback port, not Kafka) unless KAFKA_BOOTSTRAP
names a real one."""

from __future__ import annotations

import copy
import queue
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from netapp_middleware.backends.kubernetes import KubernetesBackend
from netapp_middleware.backends.local import LocalBackend
from netapp_middleware.catalogue import DEFAULT_CATALOGUE, parse_catalogue, render_spec
from netapp_middleware.channel import parse_channel

from netapp.client.middleware import MiddlewareClient
from tests.middleware.mw_helpers import DEADLINE_S, NS, ROBOTS, Operator, send_until_result
from tests.middleware.test_mw_access import era_plan


@pytest.fixture(scope="module")
def kafka() -> Iterator[str]:
    """kafka://HOST:PORT/ of a real Kafka (KAFKA_BOOTSTRAP), else of librdkafka's mock cluster."""
    pytest.importorskip("confluent_kafka")
    from tests.support.brokers import KafkaMock, kafka_bootstrap

    if kafka_bootstrap():
        yield f"kafka://{kafka_bootstrap()}/"
        return
    with KafkaMock() as mock:
        yield mock.url


def catalogue(channel: dict[str, Any]) -> dict[str, Any]:
    """The default object-detection app (its 5G-ERA task id too), its frames through `channel`."""
    app = copy.deepcopy(DEFAULT_CATALOGUE["object-detection"])
    return {"object-detection": {**app, "channel": channel}}


@pytest.mark.parametrize(
    ("channel", "says"),
    [
        ({"broker": "kafka://netapp:hunter2@k/"}, "holds a password"),
        ({"broker": "kafka://k/", "robotUrl": "kafka://robot:hunter2@k/"}, "holds a password"),
        ({"broker": "kafka://k/?password_env=X"}, "comes from secret"),
        ({"broker": "kafka://k/?netapp=x"}, "no netapp="),
        ({"broker": "kafka://k/", "robotUrl": "mqtt://k/"}, "must speak what broker does"),
        ({"broker": "redis://k/"}, "amqp://, mqtt:// or kafka://"),
        ({"broker": "kafka://k/", "secret": ""}, "must name a Secret"),
        ({"broker": "kafka://k/", "extra": 1}, "is {broker"),
        ("kafka://k/", "is {broker"),
    ],
)
def test_a_wrong_channel_is_one_line_that_names_the_app(channel, says):
    with pytest.raises(ValueError, match="app 'detect': channel") as refused:
        parse_catalogue({"detect": {"spec": {"image": "i"}, "channel": channel}})
    assert says in str(refused.value) and "hunter2" not in str(refused.value)


def test_the_netapp_consumes_as_its_own_name_and_the_robot_gets_no_password():
    channel = parse_channel({"broker": "amqp://netapp@rabbit/", "secret": "rabbit-netapp"}, "detect")
    assert channel.robot_url == "amqp://rabbit/"  # the netapp's user is not the robot's
    app = parse_catalogue(catalogue({"broker": "amqp://netapp@rabbit/", "secret": "rabbit-netapp"})).get(
        "object-detection"
    )
    spec = render_spec(app, "edge", "detect-1a2b")
    assert spec["consume"] == [{"url": "amqp://netapp@rabbit/?netapp=detect-1a2b", "secret": "rabbit-netapp"}]
    robot = parse_channel({"broker": "kafka://k/", "robotUrl": "kafka://robot@k/?password_env=KAFKA_PW"}, "d")
    assert robot.robot_url == "kafka://robot@k/?password_env=KAFKA_PW"  # where the robot finds its own


def test_the_local_backend_hands_out_the_broker_and_the_robot_streams_through_it(
    start_middleware: Any, tiny_model_path: Path, jpeg: bytes, kafka: str
) -> None:
    backend = LocalBackend(model=str(tiny_model_path), ready_timeout_s=2 * DEADLINE_S)
    server = start_middleware(backend, catalogue=catalogue({"broker": kafka}))
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        endpoint = mw.deploy("object-detection", placement="edge", timeout=2 * DEADLINE_S)
        (name,) = backend.pids()
        assert endpoint.url == f"{kafka}?netapp={name}"
        results: queue.Queue[Any] = queue.Queue()
        with mw.netapp_client(endpoint, on_result=results.put) as client:  # the URL as it came
            result = send_until_result(lambda: client.send(jpeg), results)
        assert [d["class_name"] for d in result.detections] == ["robot"]
    service = era_plan(server.url, "robot-2")  # 5G-ERA's plan carries it beside serviceUrl
    assert service["serviceBroker"].startswith(f"{kafka}?netapp=") and service["serviceUrl"].startswith("http://")


def test_the_kubernetes_backend_renders_consume_and_hands_out_the_broker(
    kube_api: Any, start_middleware: Any, kubelet: Any, jpeg: bytes, kafka: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    channel = {"broker": kafka, "robotUrl": f"{kafka}?password_env=ROBOT_KAFKA_PASSWORD"}
    server = start_middleware(KubernetesBackend(NS, kube_api.new_kube()), catalogue=catalogue(channel))
    operator = Operator(kube_api)
    mw = MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"], long_poll_s=10.0)
    found: dict[str, Any] = {}
    deploying = threading.Thread(target=lambda: found.update(endpoint=mw.deploy("object-detection", timeout=60)))
    deploying.start()
    netapp = operator.the_one()
    name = netapp["metadata"]["name"]
    assert netapp["spec"]["consume"] == [{"url": f"{kafka}?netapp={name}"}]
    url = kubelet.serve(name, spec=netapp["spec"])  # the NetApp's spec, --consume and all
    operator.set_status(name, "Ready", url=url, pool="edge-1")
    deploying.join(60)
    endpoint = found["endpoint"]
    assert endpoint.url == f"{kafka}?password_env=ROBOT_KAFKA_PASSWORD&netapp={name}"
    assert mw.status(endpoint)["url"] == endpoint.url
    monkeypatch.setenv("ROBOT_KAFKA_PASSWORD", "")  # the robot's own, given out of band (the mock takes any)
    results: queue.Queue[Any] = queue.Queue()
    with mw.netapp_client(endpoint, on_result=results.put) as client:
        result = send_until_result(lambda: client.send(jpeg), results)
    assert [d["class_name"] for d in result.detections] == ["robot"]
    mw.close()
