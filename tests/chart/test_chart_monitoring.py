"""The chart's monitoring objects: off by default; on, each one validates against the Prometheus Operator's CRD schema
(as cloudcoil's models of its CRDs give it) and selects what it claims to, the netapps the operator renders
included."""

from __future__ import annotations

import json
import re
from typing import Any

import jsonschema
import pytest
from netapp_operator import render as renderer
from netapp_operator.placement import Pool
from netapp_operator.spec import parse

from tests.chart.chart_helpers import CHART, template
from tests.support.kubernetes_versions import KUBERNETES_VERSIONS

kubernetes_validate = pytest.importorskip("kubernetes_validate")
prometheus_operator = pytest.importorskip(
    "cloudcoil.models.prometheus_operator.v1",
    reason="pip install cloudcoil-models-prometheus-operator (the test extra)",
)

MONITORING = CHART / "ci" / "monitoring-values.yaml"
KINDS = ("PodMonitor", "ServiceMonitor", "PrometheusRule")


def strict(schema: Any) -> Any:
    """The CRD's structural schema with unknown fields refused: the API server would prune them silently, so a
    misspelt field must fail here instead."""
    if isinstance(schema, dict):
        out = {k: strict(v) for k, v in schema.items()}
        if "properties" in out and "additionalProperties" not in out:
            out["additionalProperties"] = False
        return out
    if isinstance(schema, list):
        return [strict(v) for v in schema]
    return schema


# Models generated from the Prometheus Operator's CRDs; their JSON Schema is the CRDs' structural schema.
CRD_SCHEMAS = {k: strict(getattr(prometheus_operator, k).model_json_schema(by_alias=True)) for k in KINDS}


def validate(obj: dict) -> None:
    """Against its kind's schema; the schema itself is not checked as Python regexes: its patterns are Go's."""
    jsonschema.Draft202012Validator(CRD_SCHEMAS[obj["kind"]]).validate(obj)


def _kind(objects: list[dict], kind: str) -> list[dict]:
    return [o for o in objects if o["kind"] == kind]


def _named(objects: list[dict], kind: str, suffix: str) -> dict:
    [found] = [o for o in _kind(objects, kind) if o["metadata"]["name"].endswith(suffix)]
    return found


def _selects(selector: dict[str, str], labels: dict[str, str]) -> bool:
    return all(labels.get(k) == v for k, v in selector.items())


def test_off_by_default(helm):
    objects = template(helm)
    assert not [o for o in objects if o["kind"] in KINDS]
    assert not [o for o in _kind(objects, "ConfigMap") if "grafana_dashboard" in o["metadata"].get("labels", {})]
    [policy] = [p for p in _kind(objects, "NetworkPolicy") if p["metadata"]["name"].endswith("-operator")]
    # nothing scrapes the operator: it admits robots at its waker only
    assert policy["spec"]["ingress"] == [{"ports": [{"port": "waker", "protocol": "TCP"}]}]


def test_on_every_object_validates_against_its_crd_and_kubernetes(helm):
    objects = template(helm, MONITORING, namespace="netapp-system")
    assert sorted(o["kind"] for o in objects if o["kind"] in KINDS) == [
        "PodMonitor",
        "PodMonitor",
        "PrometheusRule",
        "ServiceMonitor",
    ]
    for obj in objects:
        if obj["kind"] in KINDS:
            validate(obj)
            assert obj["metadata"]["labels"]["release"] == "kube-prometheus-stack"
        elif obj["kind"] == "ConfigMap":
            for version in KUBERNETES_VERSIONS:
                kubernetes_validate.validate(obj, version, strict=True)


def test_a_misspelt_field_fails_the_schema():
    monitor = {
        "apiVersion": "monitoring.coreos.com/v1",
        "kind": "PodMonitor",
        "metadata": {"name": "x"},
        "spec": {"selector": {}, "podMetricsEndpoints": [{"port": "http", "pathh": "/metrics"}]},
    }
    with pytest.raises(jsonschema.ValidationError, match="pathh"):
        validate(monitor)


def _netapp_pod(spec: dict[str, Any]) -> dict[str, Any]:
    """The pod template the operator renders for a NetApp `det` in namespace `robots` with `spec`."""
    netapp = {
        "apiVersion": "netapp.dev/v1alpha1",
        "kind": "NetApp",
        "metadata": {"name": "det", "namespace": "robots", "uid": "u", "generation": 1},
        "spec": {"image": "ghcr.io/netapp-toolkit/netapp:0.1.0", **spec},
    }
    pool = Pool("edge", "edge", False, 0, {"nodeSelector": {"netapp.dev/pool": "edge"}}, 1, 1, ("192.168.1.10",))
    [deployment] = _kind(renderer.render(netapp, parse(netapp["spec"]), pool), "Deployment")
    return deployment["spec"]["template"]


def _meta(name: str) -> str:
    """A pod label's or annotation's name as Prometheus' Kubernetes discovery spells it in its meta labels."""
    return re.sub(r"[^a-zA-Z0-9_]", "_", name)


def _scraped_by(endpoint: dict[str, Any], pod: dict[str, Any]) -> bool:
    """Whether the endpoint's keep and drop relabelings leave `pod` as a target (as Prometheus applies them: the
    source labels joined by `;`, the regex anchored; an absent label is empty)."""
    meta = {f"__meta_kubernetes_pod_label_{_meta(k)}": v for k, v in pod["metadata"]["labels"].items()}
    meta |= {f"__meta_kubernetes_pod_annotation_{_meta(k)}": v for k, v in pod["metadata"]["annotations"].items()}
    for rule in endpoint.get("relabelings", ()):
        if rule.get("action") in ("keep", "drop"):
            value = ";".join(meta.get(label, "") for label in rule["sourceLabels"])
            matched = re.fullmatch(rule.get("regex", "(.*)"), value) is not None
            if matched != (rule["action"] == "keep"):
                return False
    return True


def test_the_netapp_podmonitor_selects_the_pods_the_operator_renders(helm, tmp_path):
    monitor = _named(template(helm, MONITORING), "PodMonitor", "-netapps")
    pod = _netapp_pod({})
    assert _selects(monitor["spec"]["selector"]["matchLabels"], pod["metadata"]["labels"])
    assert monitor["spec"]["namespaceSelector"] == {"matchNames": ["robots"]}  # the operator's watched namespace
    [container] = pod["spec"]["containers"]
    for endpoint in monitor["spec"]["podMetricsEndpoints"]:
        assert endpoint["port"] in {p["name"] for p in container["ports"]} and endpoint["path"] == "/metrics"
        # The labels the rules and dashboards group by come from labels every netapp pod has.
        relabeled = {r["targetLabel"]: r["sourceLabels"][0] for r in endpoint["relabelings"] if "targetLabel" in r}
        for source in relabeled.values():
            assert source in {f"__meta_kubernetes_pod_label_{_meta(k)}" for k in pod["metadata"]["labels"]}
        assert set(relabeled) == {"netapp", "pool"}
    # A cluster-wide operator: netapps in any namespace.
    values = tmp_path / "values.yaml"
    values.write_text("monitoring: {serviceMonitors: {enabled: true}}\n")
    assert _named(template(helm, values), "PodMonitor", "-netapps")["spec"]["namespaceSelector"] == {"any": True}


def test_netapps_with_tls_are_scraped_over_https_and_the_others_over_http(helm, tmp_path):
    """Each netapp pod is a target of exactly one endpoint: HTTP, or HTTPS with the tlsConfig of the values where
    its NetApp has spec.tls (its probes speak HTTPS there too)."""
    http, https = _named(template(helm, MONITORING), "PodMonitor", "-netapps")["spec"]["podMetricsEndpoints"]
    assert http.get("scheme", "http") == "http" and "tlsConfig" not in http
    assert https["scheme"] == "https" and https["tlsConfig"] == {"insecureSkipVerify": True}  # by default
    plain, tls = _netapp_pod({}), _netapp_pod({"tls": {"secretName": "det-tls"}})
    assert tls["spec"]["containers"][0]["readinessProbe"]["httpGet"]["scheme"] == "HTTPS"
    assert [_scraped_by(e, plain) for e in (http, https)] == [True, False]
    assert [_scraped_by(e, tls) for e in (http, https)] == [False, True]
    values = tmp_path / "values.yaml"
    verified = {"ca": {"secret": {"name": "netapp-ca", "key": "ca.crt"}}, "serverName": "netapp.robots.svc"}
    values.write_text(json.dumps({"monitoring": {"serviceMonitors": {"enabled": True, "netappTLS": verified}}}))
    monitor = _named(template(helm, values), "PodMonitor", "-netapps")
    validate(monitor)
    assert monitor["spec"]["podMetricsEndpoints"][1]["tlsConfig"] == verified


def test_the_control_plane_monitors_select_its_pods_and_service(helm):
    objects = template(helm, MONITORING)
    operator = _named(objects, "Deployment", "-operator")["spec"]["template"]
    monitor = _named(objects, "PodMonitor", "-operator")
    assert _selects(monitor["spec"]["selector"]["matchLabels"], operator["metadata"]["labels"])
    [container] = operator["spec"]["containers"]
    ports = {p["name"]: p["containerPort"] for p in container["ports"]}
    assert f"--metrics=http://0.0.0.0:{ports['metrics']}/metrics" in container["args"]
    assert [e["port"] for e in monitor["spec"]["podMetricsEndpoints"]] == ["metrics"]
    [policy] = [p for p in _kind(objects, "NetworkPolicy") if p["metadata"]["name"].endswith("-operator")]
    waker = {"ports": [{"port": "waker", "protocol": "TCP"}]}
    assert policy["spec"]["ingress"] == [waker, {"ports": [{"port": "metrics", "protocol": "TCP"}]}]
    service = _named(objects, "Service", "-middleware")
    monitor = _named(objects, "ServiceMonitor", "-middleware")
    assert _selects(monitor["spec"]["selector"]["matchLabels"], service["metadata"]["labels"])
    assert [e["port"] for e in monitor["spec"]["endpoints"]] == [p["name"] for p in service["spec"]["ports"]]
    selected = [
        s
        for s in _kind(objects, "Service")
        if _selects(monitor["spec"]["selector"]["matchLabels"], s["metadata"]["labels"])
    ]
    assert selected == [service]


def test_dashboards_are_configmaps_for_grafanas_sidecar(helm):
    maps = [m for m in _kind(template(helm, MONITORING), "ConfigMap") if m["metadata"]["name"].count("-dashboard-")]
    files = sorted(p.name for p in (CHART / "files" / "dashboards").glob("*.json"))
    assert files and sorted(k for m in maps for k in m["data"]) == files
    for m in maps:
        assert m["metadata"]["labels"]["grafana_dashboard"] == "1"
        assert m["metadata"]["annotations"] == {"grafana_folder": "Robots"}
        [(name, text)] = m["data"].items()
        assert json.loads(text) == json.loads((CHART / "files" / "dashboards" / name).read_text())


def test_rules_take_the_values_and_leave_no_placeholder(helm):
    objects = template(helm, MONITORING)
    [rule] = _kind(objects, "PrometheusRule")
    alerts = {r["alert"]: r for g in rule["spec"]["groups"] for r in g["rules"] if "alert" in r}
    assert alerts["NetAppLatencyHigh"]["expr"].endswith("> 0.25") and alerts["NetAppLatencyHigh"]["for"] == "10m"
    assert "${" not in json.dumps(rule)
    for name, alert in alerts.items():
        assert alert["labels"]["severity"] in ("warning", "critical")
        assert alert["annotations"]["summary"] and alert["annotations"]["description"]
        assert alert["annotations"]["runbook_url"].endswith("docs/operating.md#" + name.lower())
