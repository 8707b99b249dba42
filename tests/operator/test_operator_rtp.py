"""A NetApp's `spec.rtp`: its UDP ports in the netapp's args, its container, its Service (nodePort = port where
a node can take it) and its NetworkPolicy; what is wrong with it, said in one sentence; the CRD's schema."""

from __future__ import annotations

import jsonschema
import pytest
from netapp_operator.spec import parse

from tests.operator.test_operator_render import kinds, netapp, pool, render
from tests.support.kube_emulator import load_crds

NETAPP_SCHEMA = next(c for c in load_crds() if c["spec"]["names"]["kind"] == "NetApp")["spec"]["versions"][0]


def children(service_type: str = "NodePort", **rtp) -> dict:
    na = netapp(rtp={"firstPort": 31000, "count": 3, **rtp})
    return kinds(render(na, pool(access={"serviceType": service_type})))


def test_the_ports_reach_the_args_the_container_the_service_and_the_policy():
    made = children()
    container = made["Deployment"]["spec"]["template"]["spec"]["containers"][0]
    assert container["args"][container["args"].index("--rtp-ports") + 1] == "31000-31002"
    udp = [p for p in container["ports"] if p["protocol"] == "UDP"]
    assert [p["containerPort"] for p in udp] == [31000, 31001, 31002]
    service = [p for p in made["Service"]["spec"]["ports"] if p["protocol"] == "UDP"]
    assert [(p["port"], p["targetPort"], p["nodePort"]) for p in service] == [(n, n, n) for n in (31000, 31001, 31002)]
    [rule] = made["NetworkPolicy"]["spec"]["ingress"]
    assert {"port": 31000, "endPort": 31002, "protocol": "UDP"} in rule["ports"]


def test_ports_outside_the_node_port_range_get_no_node_port_and_clusterip_none():
    outside = [p for p in children(firstPort=50000)["Service"]["spec"]["ports"] if p["protocol"] == "UDP"]
    assert outside and all("nodePort" not in p for p in outside)
    inside = [p for p in children("ClusterIP")["Service"]["spec"]["ports"] if p["protocol"] == "UDP"]
    assert inside and all("nodePort" not in p for p in inside)


def test_without_rtp_nothing_udp_is_rendered():
    made = kinds(render(netapp(), pool()))
    assert "--rtp-ports" not in made["Deployment"]["spec"]["template"]["spec"]["containers"][0]["args"]
    assert all(p["protocol"] == "TCP" for p in made["Service"]["spec"]["ports"])


@pytest.mark.parametrize(
    ("spec", "says"),
    [
        ({"rtp": {"firstPort": 31000, "count": 100}}, "1..64"),
        ({"rtp": {"firstPort": 80}}, "1024-65535"),
        ({"rtp": {"firstPort": "31000"}}, "integers"),
        ({"rtp": {"firstPort": 31000}, "replicas": 2}, "replicas: 1"),
        ({"rtp": {"firstPort": 31000}, "autoscaling": {"maxReplicas": 3}}, "replicas: 1"),
    ],
)
def test_what_is_wrong_is_one_sentence(spec, says):
    problems = [p for p in parse({"image": "i", **spec}).problems if "rtp" in p]
    assert len(problems) == 1 and says in problems[0]


def test_the_crd_takes_rtp_and_refuses_a_range_too_long():
    schema = NETAPP_SCHEMA["schema"]["openAPIV3Schema"]
    jsonschema.validate({"spec": {"image": "i", "rtp": {"firstPort": 31000, "count": 8}}}, schema)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({"spec": {"image": "i", "rtp": {"firstPort": 31000, "count": 1000}}}, schema)
