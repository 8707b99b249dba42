"""Access control of a NetApp, rendered (pure): the token Secret, the token in the netapp's environment, TLS
(certificate mounted, server flags, HTTPS probes and URL) and the NetworkPolicy that admits only its port."""

from __future__ import annotations

import base64

from netapp_operator import render as renderer
from netapp_operator.constants import TLS_DIR
from netapp_operator.spec import parse

from netapp.protocol import ADVERTISE_URL_ENV
from tests.operator.test_operator_render import UID, kinds, netapp, pool, render, service_url


def _container(manifests: list[dict]) -> dict:
    [container] = kinds(manifests)["Deployment"]["spec"]["template"]["spec"]["containers"]
    return container


def test_spec_access_defaults_to_open_and_no_tls():
    spec = parse({"image": "i"})
    assert spec.access.require_token is False and spec.tls is None and not spec.problems
    assert parse({"image": "i", "access": {"requireToken": True}}).access.require_token is True


def test_spec_rejects_malformed_access_and_tls():
    problems = parse({"image": "i", "access": {"requireToken": "yes"}, "tls": {"secretName": ""}}).problems
    assert "spec.access.requireToken must be true or false, got 'yes'" in problems
    assert "spec.tls.secretName must name a kubernetes.io/tls Secret" in problems


def test_token_secret_is_owned_by_the_netapp_and_holds_the_token():
    secret = renderer.render_token_secret(netapp(), "s3cret")
    assert secret["metadata"]["name"] == "det-token" and secret["metadata"]["namespace"] == "robots"
    [ref] = secret["metadata"]["ownerReferences"]
    assert ref["uid"] == UID and ref["kind"] == "NetApp" and ref["controller"] is True
    assert base64.b64decode(secret["data"]["token"]) == b"s3cret"
    # Not a child: the reconciler creates it once and never applies it again.
    assert "Secret" not in kinds(render(netapp(access={"requireToken": True}), pool()))


def test_required_token_comes_from_the_secret_as_an_environment_variable():
    open_env = _container(render(netapp(), pool()))["env"]
    assert all(e["name"] != "NETAPP_TOKEN" for e in open_env)
    env = _container(render(netapp(access={"requireToken": True}, env=[{"name": "A", "value": "1"}]), pool()))["env"]
    assert env[-2:] == [  # after the replica's own (POD_IP, advertise URL, cluster key)
        {"name": "A", "value": "1"},
        {"name": "NETAPP_TOKEN", "valueFrom": {"secretKeyRef": {"name": "det-token", "key": "token"}}},
    ]


def test_tls_mounts_the_certificate_and_serves_https():
    manifests = render(netapp(tls={"secretName": "det-cert"}), pool())
    container = _container(manifests)
    args = container["args"]
    assert args[args.index("--tls-cert") + 1] == f"{TLS_DIR}/tls.crt"
    assert args[args.index("--tls-key") + 1] == f"{TLS_DIR}/tls.key"
    assert {"name": "tls", "mountPath": TLS_DIR, "readOnly": True} in container["volumeMounts"]
    volumes = kinds(manifests)["Deployment"]["spec"]["template"]["spec"]["volumes"]
    assert {"name": "tls", "secret": {"secretName": "det-cert", "defaultMode": 0o440}} in volumes
    for probe in ("startupProbe", "livenessProbe", "readinessProbe"):
        assert container[probe]["httpGet"]["scheme"] == "HTTPS"
    plain = _container(render(netapp(), pool()))
    assert "--tls-cert" not in plain["args"] and "scheme" not in plain["readinessProbe"]["httpGet"]


def test_with_tls_replicas_reach_each_other_over_https():
    """The other replicas verify it against the certificate they share: no CA to render (netapp serve's default)."""
    env = {e["name"]: e for e in _container(render(netapp(tls={"secretName": "det-cert"}), pool()))["env"]}
    assert env[ADVERTISE_URL_ENV]["value"].startswith("https://$(POD_IP):")
    plain = {e["name"]: e for e in _container(render(netapp(), pool()))["env"]}
    assert plain[ADVERTISE_URL_ENV]["value"].startswith("http://$(POD_IP):")


def test_tls_makes_the_url_https():
    service = {"spec": {"ports": [{"name": "http", "nodePort": 30001}]}}
    assert service_url(netapp(tls={"secretName": "c"}), pool(), service) == "https://192.168.1.10:30001"
    assert service_url(netapp(), pool(), service) == "http://192.168.1.10:30001"
    templated = pool(access={"serviceType": "NodePort", "urlTemplate": "{scheme}://edge.example:{nodePort}"})
    assert service_url(netapp(tls={"secretName": "c"}), templated, service) == "https://edge.example:30001"


def test_network_policy_admits_only_the_netapp_port_to_its_pods():
    manifests = render(netapp(port=7000), pool())
    policy = kinds(manifests)["NetworkPolicy"]
    deployment = kinds(manifests)["Deployment"]
    assert policy["metadata"]["name"] == deployment["metadata"]["name"]
    assert policy["spec"]["podSelector"]["matchLabels"] == deployment["spec"]["selector"]["matchLabels"]
    assert policy["spec"]["policyTypes"] == ["Ingress"]
    assert policy["spec"]["ingress"] == [{"ports": [{"port": 7000, "protocol": "TCP"}]}]
