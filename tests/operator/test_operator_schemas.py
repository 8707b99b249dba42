"""Every rendered child and every CRD validated against the Kubernetes schemas (kubernetes-validate); the
examples validated against the CRDs' own structural schemas, which also reject malformed NetApps."""

from __future__ import annotations

import itertools

import jsonschema
import pytest
import yaml

kubernetes_validate = pytest.importorskip("kubernetes_validate")

from netapp_operator.placement import Pool  # noqa: E402
from netapp_operator.render import render, render_standby, render_token_secret  # noqa: E402
from netapp_operator.spec import parse  # noqa: E402

from tests.support.kube_emulator import load_crds  # noqa: E402
from tests.support.kubernetes_versions import KUBERNETES_VERSIONS  # noqa: E402
from tests.support.paths import ROOT  # noqa: E402

SPECS = {
    "minimal": {"image": "img"},
    "full": {
        "image": "img",
        "args": ["--x"],
        "env": [{"name": "A", "value": "1"}],
        "port": 8080,
        "model": {"url": "https://m/x.onnx", "sha256": "0" * 64, "timeoutSeconds": 30},
        "autoscaling": {"minReplicas": 1, "maxReplicas": 3},
        "resources": {"cpu": "1", "memory": "1Gi", "gpus": 1},
    },
    "volume-model": {"image": "img", "replicas": 0, "model": {"volume": {"claimName": "c", "path": "m.onnx"}}},
    "token-and-tls": {"image": "img", "access": {"requireToken": True}, "tls": {"secretName": "det-cert"}},
    "measured-admission": {"image": "img", "admission": "measured"},
    "priorities": {
        "image": "img",
        "priority": {"robots": "low", "tokenSha256": {"high": "a" * 64}, "weights": {"low": 1, "high": 8.5}},
    },
    "scale-on-robots": {"image": "img", "autoscaling": {"maxReplicas": 4, "metric": "robotsPerReplica", "target": 3}},
    "standby": {"image": "img", "standby": {"replicas": 2}, "autoscaling": {"maxReplicas": 3}},
    "tensorrt-emptydir": {"image": "img", "device": "tensorrt", "fp16": True},
    "tensorrt-claim": {"image": "img", "device": "tensorrt", "engineCache": {"claimName": "engines"}},
    "cuda": {"image": "img", "device": "cuda", "resources": {"gpus": 2}},
    "rtp": {"image": "img", "rtp": {"firstPort": 31000, "count": 4}},
    "cameras": {"image": "img", "replicas": 2, "sources": [{"name": "door", "url": "rtsp://10.0.0.5/s"}]},
    "idle-to-zero": {"image": "img", "scaling": {"idleToZero": "5m"}},
}
POOLS = {
    "edge-nodeport": Pool(
        "edge", "edge", False, 1, {"nodeSelector": {"p": "e"}, "access": {"serviceType": "NodePort"}}
    ),
    "cloud-lb-gpu": Pool(
        "cloud",
        "cloud",
        True,
        0,
        {
            "nodeSelector": {"p": "c"},
            "gpu": True,
            "access": {"serviceType": "LoadBalancer"},
            "tolerations": [{"key": "gpu", "operator": "Exists", "effect": "NoSchedule"}],
            "affinity": {
                "nodeAffinity": {
                    "requiredDuringSchedulingIgnoredDuringExecution": {
                        "nodeSelectorTerms": [
                            {"matchExpressions": [{"key": "zone", "operator": "In", "values": ["a"]}]}
                        ]
                    }
                }
            },
        },
    ),
    "clusterip": Pool("dc", "cloud", False, 0, {"nodeSelector": {"p": "d"}, "access": {"serviceType": "ClusterIP"}}),
}


@pytest.mark.parametrize("spec_name, pool_name", list(itertools.product(SPECS, POOLS)))
def test_rendered_children_are_valid_kubernetes(spec_name, pool_name):
    na = {"metadata": {"name": "det", "namespace": "ns", "uid": "u-1"}, "spec": SPECS[spec_name]}
    spec = parse(na["spec"])
    for manifest in [*render(na, spec, POOLS[pool_name]), *render_standby(na, spec, POOLS[pool_name])]:
        for version in KUBERNETES_VERSIONS:
            kubernetes_validate.validate(manifest, version, strict=True)


def test_token_secret_is_valid_kubernetes():
    na = {"metadata": {"name": "det", "namespace": "ns", "uid": "u-1"}, "spec": {"image": "img"}}
    for version in KUBERNETES_VERSIONS:
        kubernetes_validate.validate(render_token_secret(na, "t0ken"), version, strict=True)


def test_the_cluster_key_secret_is_valid_kubernetes():
    from netapp_operator.render import render_cluster_key_secret

    secret = render_cluster_key_secret({"metadata": {"name": "det", "namespace": "ns", "uid": "u-1"}}, "k" * 64)
    for version in KUBERNETES_VERSIONS:
        kubernetes_validate.validate(secret, version, strict=True)


def test_crds_are_valid_kubernetes():
    crds = load_crds()
    assert {c["metadata"]["name"] for c in crds} == {"netapps.netapp.dev", "nodepools.netapp.dev"}
    for crd in crds:
        for version in KUBERNETES_VERSIONS:
            kubernetes_validate.validate(crd, version, strict=True)


def _schema(kind: str) -> dict:
    [crd] = [c for c in load_crds() if c["spec"]["names"]["kind"] == kind]
    [version] = crd["spec"]["versions"]
    return version["schema"]["openAPIV3Schema"]


def _examples() -> list[dict]:
    docs = []
    for path in sorted((ROOT / "manifests" / "examples").glob("*.yaml")):
        docs += [d for d in yaml.safe_load_all(path.read_text()) if d]
    return docs


def test_examples_match_the_crd_schemas():
    examples = _examples()
    assert {d["kind"] for d in examples} == {"NetApp", "NodePool"}
    assert {d["spec"]["type"] for d in examples if d["kind"] == "NodePool"} == {"edge", "cloud"}
    for doc in examples:
        jsonschema.validate(doc, _schema(doc["kind"]))


@pytest.mark.parametrize(
    "spec, words",
    [
        ({}, "'image' is a required property"),
        ({"image": ""}, "should be non-empty"),
        ({"image": "i", "replicas": -1}, "less than the minimum"),
        ({"image": "i", "placement": {"policy": "moon"}}, "is not one of"),
        ({"image": "i", "model": {"url": "https://x", "sha256": "nothex"}}, "does not match"),
        ({"image": "i", "access": {"requireToken": "yes"}}, "is not of type 'boolean'"),
        ({"image": "i", "tls": {}}, "'secretName' is a required property"),
        ({"image": "i", "autoscaling": {"maxReplicas": 2, "metric": "gpu"}}, "is not one of"),
        ({"image": "i", "autoscaling": {"maxReplicas": 2, "engine": "knative"}}, "is not one of"),
        ({"image": "i", "autoscaling": {"maxReplicas": 2, "target": 0}}, "less than the minimum"),
        ({"image": "i", "admission": "strict"}, "is not one of"),
        ({"image": "i", "priority": {"robots": "vip"}}, "is not one of"),
        ({"image": "i", "priority": {"tokenSha256": {"vip": "a" * 64}}}, "Additional properties"),
        ({"image": "i", "priority": {"tokenSha256": {"high": "nothex"}}}, "does not match"),
        ({"image": "i", "priority": {"weights": {"high": -1}}}, "less than the minimum"),
        ({"image": "i", "priority": {"weights": {"vip": 2}}}, "Additional properties"),
        ({"image": "i", "standby": {"replicas": 9}}, "greater than the maximum"),
        ({"image": "i", "standby": {"policy": "random"}}, "is not one of"),
        ({"image": "i", "device": "tpu"}, "is not one of"),
        ({"image": "i", "fp16": "yes"}, "is not of type 'boolean'"),
        ({"image": "i", "engineCache": {"claimName": ""}}, "should be non-empty"),
        ({"image": "i", "scaling": {"idleToZero": "soon"}}, "does not match"),
    ],
)
def test_crd_schema_rejects_malformed_netapps(spec, words):
    doc = {"apiVersion": "netapp.dev/v1alpha1", "kind": "NetApp", "metadata": {"name": "x"}, "spec": spec}
    with pytest.raises(jsonschema.ValidationError, match=words):
        jsonschema.validate(doc, _schema("NetApp"))


def test_crd_schema_takes_every_autoscaling_form():
    for auto in (
        {"maxReplicas": 3, "metric": "latency", "target": 0.25},
        {"maxReplicas": 3, "metric": "queueDepth", "engine": "keda", "prometheusAddress": "http://prom:9090"},
    ):
        doc = {"apiVersion": "netapp.dev/v1alpha1", "kind": "NetApp", "metadata": {"name": "x"}}
        jsonschema.validate(doc | {"spec": {"image": "i", "autoscaling": auto}}, _schema("NetApp"))


def test_crd_schema_rejects_a_nodepool_without_type():
    doc = {
        "apiVersion": "netapp.dev/v1alpha1",
        "kind": "NodePool",
        "metadata": {"name": "x"},
        "spec": {"nodeSelector": {"a": "b"}},
    }
    with pytest.raises(jsonschema.ValidationError, match="'type' is a required property"):
        jsonschema.validate(doc, _schema("NodePool"))


def test_the_crd_and_the_values_schema_name_the_netapps_devices():
    """The devices a NetApp and a catalogue app take are the ones `netapp serve --device` knows (netapp.protocol)."""
    import json

    from netapp.protocol import DEVICES

    assert tuple(_schema("NetApp")["properties"]["spec"]["properties"]["device"]["enum"]) == DEVICES
    values = json.loads((ROOT / "charts" / "netapp-toolkit" / "values.schema.json").read_text())
    assert tuple(values["definitions"]["app"]["properties"]["spec"]["properties"]["device"]["enum"]) == DEVICES
