"""Autoscaling on the netapps' own signals: HPAs validated against the Kubernetes schemas, ScaledObjects against
the KEDA schema subset in tests/support/schemas (written from KEDA's documented fields; see that file)."""

from __future__ import annotations

import pathlib

import jsonschema
import pytest
import yaml
from netapp_operator.autoscaling import quantity, render_autoscaler
from netapp_operator.placement import Pool
from netapp_operator.render import render
from netapp_operator.spec import AUTOSCALING_METRICS as METRICS
from netapp_operator.spec import parse

from netapp.protocol import METRIC_LATENCY, METRIC_ROBOTS
from tests.support.kubernetes_versions import KUBERNETES_VERSIONS

KEDA_SCHEMA = yaml.safe_load(
    (pathlib.Path(__file__).parents[1] / "support" / "schemas" / "keda-scaledobject-v1alpha1.yaml").read_text()
)
META = {"name": "det-edge", "namespace": "ns", "labels": {"app.kubernetes.io/name": "netapp"}}
PROMETHEUS = "http://prometheus.monitoring.svc:9090"


def Autoscaling(min_replicas, max_replicas, **fields):  # noqa: N802 (reads like the spec's class)
    """spec.Autoscaling through the spec's own parser, so defaults and checks are the operator's."""
    names = {"target_cpu_percent": "targetCPUUtilizationPercentage", "prometheus_address": "prometheusAddress"}
    raw = {"minReplicas": min_replicas, "maxReplicas": max_replicas, **{names.get(k, k): v for k, v in fields.items()}}
    return parse({"image": "img", "autoscaling": raw}).autoscaling


def problems(auto_fields: dict) -> list[str]:
    return list(parse({"image": "img", "autoscaling": {"maxReplicas": 3, **auto_fields}}).problems)


@pytest.mark.parametrize("metric", METRICS)
def test_every_hpa_is_valid_kubernetes(metric):
    kubernetes_validate = pytest.importorskip("kubernetes_validate")
    hpa = render_autoscaler(META, "det-edge", Autoscaling(1, 5, metric=metric))
    for version in KUBERNETES_VERSIONS:
        kubernetes_validate.validate(hpa, version, strict=True)


@pytest.mark.parametrize("metric", METRICS)
def test_every_scaled_object_is_valid_keda(metric):
    scaled = render_autoscaler(
        META, "det-edge", Autoscaling(1, 5, metric=metric, engine="keda", prometheus_address=PROMETHEUS)
    )
    jsonschema.validate(scaled, KEDA_SCHEMA)


def test_the_keda_schema_refuses_what_keda_would_not_take():
    scaled = render_autoscaler(
        META, "d", Autoscaling(1, 5, metric="latency", engine="keda", prometheus_address=PROMETHEUS)
    )
    for broken in (
        {**scaled, "spec": {**scaled["spec"], "triggers": []}},
        {**scaled, "spec": {**scaled["spec"], "maxReplicas": 3}},  # HPA's spelling, not KEDA's
        {**scaled, "spec": {**scaled["spec"], "triggers": [{"type": "prometheus", "metadata": {"query": "x"}}]}},
    ):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(broken, KEDA_SCHEMA)


def test_an_hpa_on_robots_per_replica_is_a_pods_metric():
    hpa = render_autoscaler(META, "det-edge", Autoscaling(2, 6, metric="robotsPerReplica", target=3))
    assert hpa["spec"]["minReplicas"] == 2 and hpa["spec"]["maxReplicas"] == 6
    assert hpa["spec"]["scaleTargetRef"] == {"apiVersion": "apps/v1", "kind": "Deployment", "name": "det-edge"}
    assert hpa["spec"]["metrics"] == [
        {
            "type": "Pods",
            "pods": {"metric": {"name": METRIC_ROBOTS}, "target": {"type": "AverageValue", "averageValue": "3"}},
        }
    ]


def test_cpu_stays_a_resource_metric():
    (metric,) = render_autoscaler(META, "d", Autoscaling(1, 3, target_cpu_percent=60))["spec"]["metrics"]
    target = {"type": "Utilization", "averageUtilization": 60}
    assert metric == {"type": "Resource", "resource": {"name": "cpu", "target": target}}


def test_a_latency_target_is_a_milli_quantity_and_keda_averages_it():
    (metric,) = render_autoscaler(META, "d", Autoscaling(1, 3, metric="latency", target=0.25))["spec"]["metrics"]
    assert metric["pods"]["target"]["averageValue"] == "250m"
    scaled = render_autoscaler(
        META, "det-edge", Autoscaling(1, 3, metric="latency", target=0.25, engine="keda", prometheus_address=PROMETHEUS)
    )
    (trigger,) = scaled["spec"]["triggers"]
    assert trigger["type"] == "prometheus" and trigger["metricType"] == "Value"
    assert trigger["metadata"]["threshold"] == "0.25"
    pods = 'pod=~"det-edge-[a-z0-9]+-[a-z0-9]+"'
    assert trigger["metadata"]["query"] == f'avg({METRIC_LATENCY}{{namespace="ns",{pods}}})'
    assert scaled["spec"]["minReplicaCount"] == 1 and scaled["spec"]["maxReplicaCount"] == 3


def test_keda_sums_an_additive_signal_against_a_per_replica_threshold():
    scaled = render_autoscaler(
        META, "d", Autoscaling(1, 3, metric="robotsPerReplica", engine="keda", prometheus_address=PROMETHEUS)
    )
    (trigger,) = scaled["spec"]["triggers"]
    assert trigger["metricType"] == "AverageValue" and trigger["metadata"]["threshold"] == "4"
    assert trigger["metadata"]["query"].startswith(f"sum({METRIC_ROBOTS}{{")


def test_problems_say_what_to_fix():
    assert problems({"metric": "latency", "target": 0.2}) == []
    assert "prometheusAddress is required" in problems({"metric": "latency", "engine": "keda"})[0]
    assert problems({"metric": "cpu", "engine": "keda"}) == []  # KEDA's cpu trigger needs no Prometheus
    assert "metric must be one of" in problems({"metric": "gpu"})[0]
    assert "engine must be hpa or keda" in problems({"engine": "knative"})[0]
    assert "target must be a number > 0" in problems({"metric": "latency", "target": 0})[0]
    assert "target must be a number > 0" in problems({"metric": "latency", "target": "fast"})[0]


def test_render_gives_the_scaled_object_and_no_replica_count():
    netapp = {"metadata": {"name": "det", "namespace": "ns", "uid": "u-1"}}
    spec = parse(
        {
            "image": "img",
            "autoscaling": {
                "maxReplicas": 4,
                "metric": "capacityLoad",
                "engine": "keda",
                "prometheusAddress": PROMETHEUS,
            },
        }
    )
    deployment, _service, _policy, scaled = render(netapp, spec, Pool("edge", "edge", False, 1, {}))
    assert "replicas" not in deployment["spec"]  # KEDA's HPA owns the count
    assert scaled["kind"] == "ScaledObject" and scaled["metadata"]["name"] == deployment["metadata"]["name"]
    jsonschema.validate(scaled, KEDA_SCHEMA)
    assert scaled["spec"]["triggers"][0]["metadata"]["threshold"] == "0.9"


def test_quantities():
    assert [quantity(v) for v in (4, 4.0, 0.25, 1.5)] == ["4", "4", "250m", "1500m"]
