"""The Helm chart: lint, render with three value sets, validate every object against the supported Kubernetes
versions, check the security defaults, reject bad values, and keep manifests/ rendered from it."""

from __future__ import annotations

import jsonschema
import pytest
import yaml
from netapp_operator.spec import parse

from tests.chart.chart_helpers import CHART, ROOT, run, template
from tests.support.kube_emulator import load_crds
from tests.support.kubernetes_versions import KUBERNETES_VERSIONS

kubernetes_validate = pytest.importorskip("kubernetes_validate")

VALUE_SETS = {
    "defaults": [],
    "edge-only": [CHART / "ci" / "edge-only-values.yaml"],
    "edge-cloud-gpu": [CHART / "ci" / "edge-cloud-gpu-values.yaml"],
    "kind": [CHART / "ci" / "kind-values.yaml"],
}
CRD_SCHEMAS = {c["spec"]["names"]["kind"]: c["spec"]["versions"][0]["schema"]["openAPIV3Schema"] for c in load_crds()}


@pytest.mark.parametrize("name", VALUE_SETS)
def test_helm_lint(helm, name):
    flags = [f for v in VALUE_SETS[name] for f in ("--values", v)]
    result = run(helm, "lint", "--strict", CHART, *flags, check=False)
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.parametrize("name", VALUE_SETS)
def test_every_rendered_object_is_valid_on_every_supported_version(helm, name):
    objects = template(helm, *VALUE_SETS[name])
    assert objects
    for obj in objects:
        if obj["kind"] in CRD_SCHEMAS:  # custom resources: against the CRD's own schema
            jsonschema.validate(obj, CRD_SCHEMAS[obj["kind"]])
            continue
        for version in KUBERNETES_VERSIONS:
            kubernetes_validate.validate(obj, version, strict=True)


def _by_kind(objects: list[dict], kind: str) -> list[dict]:
    return [o for o in objects if o["kind"] == kind]


@pytest.mark.parametrize("name", VALUE_SETS)
def test_security_defaults(helm, name):
    objects = template(helm, *VALUE_SETS[name])
    for dep in _by_kind(objects, "Deployment"):
        pod = dep["spec"]["template"]["spec"]
        assert pod["securityContext"]["runAsNonRoot"] is True
        assert pod["securityContext"]["seccompProfile"] == {"type": "RuntimeDefault"}
        for c in pod["containers"]:
            sc = c["securityContext"]
            assert sc["readOnlyRootFilesystem"] and not sc["allowPrivilegeEscalation"]
            assert sc["capabilities"] == {"drop": ["ALL"]}
            assert c["livenessProbe"] and c["readinessProbe"]
            assert c["resources"]["requests"] and c["resources"]["limits"]["memory"]
    for binding in _by_kind(objects, "ClusterRoleBinding") + _by_kind(objects, "RoleBinding"):
        assert binding["roleRef"]["name"] not in ("cluster-admin", "admin", "edit")
    for role in _by_kind(objects, "ClusterRole") + _by_kind(objects, "Role"):
        for rule in role["rules"]:
            assert "*" not in rule["verbs"] and "*" not in rule["resources"] and "*" not in rule["apiGroups"]
            if "secrets" in rule["resources"]:
                # Only NetApps' token and cluster key Secrets, which the operator creates (it never reads any Secret).
                assert rule["resources"] == ["secrets"] and rule["verbs"] == ["create"]
                assert role["metadata"]["labels"]["app.kubernetes.io/component"] == "operator"


def test_middleware_contract(helm):
    objects = template(helm, *VALUE_SETS["edge-only"])
    [dep] = [d for d in _by_kind(objects, "Deployment") if d["metadata"]["name"].endswith("-middleware")]
    [c] = dep["spec"]["template"]["spec"]["containers"]
    assert c["args"] == [
        "--log-level=INFO",
        "middleware",
        "--backend=kubernetes",
        "--namespace=robots",
        "--robots-file=/etc/netapp/robots/robots.yaml",
        "--catalogue-file=/etc/netapp/catalogue/catalogue.yaml",
        "--port=8080",
        "--token-key-file=/etc/netapp/token/token-key",  # always a stable key: one the chart draws by default
    ]
    assert c["livenessProbe"]["httpGet"]["path"] == "/healthz"
    [role] = [r for r in _by_kind(objects, "Role") if r["metadata"]["name"].endswith("-middleware")]
    assert role["metadata"]["namespace"] == "robots"
    assert role["rules"] == [
        {
            "apiGroups": ["netapp.dev"],
            "resources": ["netapps"],
            "verbs": ["create", "get", "list", "watch", "patch", "delete"],
        }
    ]
    [secret] = [s for s in _by_kind(objects, "Secret") if s["metadata"]["name"].endswith("-robots")]
    robots = yaml.safe_load(secret["stringData"]["robots.yaml"])
    assert robots["robots"][0]["id"] == "robot-1" and robots["robots"][0]["secretHash"].startswith("scrypt$")
    [cm] = _by_kind(objects, "ConfigMap")
    catalogue = yaml.safe_load(cm["data"]["catalogue.yaml"])
    assert catalogue["object-detection"]["spec"]["image"] == "ghcr.io/netapp-toolkit/netapp:0.1.0"
    # Every catalogue entry's spec is a NetApp spec the CRD accepts.
    for app in catalogue.values():
        jsonschema.validate(
            {"apiVersion": "netapp.dev/v1alpha1", "kind": "NetApp", "metadata": {"name": "x"}, "spec": app["spec"]},
            CRD_SCHEMAS["NetApp"],
        )
    # Namespaced operator: a Role in the watched namespace, cluster-wide only nodes and NodePools.
    [op_role] = [r for r in _by_kind(objects, "Role") if r["metadata"]["name"].endswith("-operator")]
    assert op_role["metadata"]["namespace"] == "robots"
    [cluster_role] = _by_kind(objects, "ClusterRole")
    assert {r for rule in cluster_role["rules"] for r in rule["resources"]} == {
        "nodes",
        "nodepools",
        "nodepools/status",
    }
    [op] = [d for d in _by_kind(objects, "Deployment") if d["metadata"]["name"].endswith("-operator")]
    assert "--namespace=robots" in op["spec"]["template"]["spec"]["containers"][0]["args"]


def test_gpu_cloud_values(helm):
    objects = template(helm, *VALUE_SETS["edge-cloud-gpu"])
    pools = {p["metadata"]["name"]: p["spec"] for p in _by_kind(objects, "NodePool")}
    assert pools["cloud-gpu"]["gpu"] is True and pools["cloud-gpu"]["access"]["serviceType"] == "LoadBalancer"
    assert pools["edge"]["type"] == "edge"
    [ingress] = _by_kind(objects, "Ingress")
    assert ingress["spec"]["tls"] == [{"hosts": ["netapp.robots.example.com"], "secretName": "netapp-tls"}]
    # robots come from the existing Secret; the one made is the operator's rollout token
    assert [s["metadata"]["name"] for s in _by_kind(objects, "Secret")] == ["netapp-toolkit-operator-rollout-token"]
    [dep] = [d for d in _by_kind(objects, "Deployment") if d["metadata"]["name"].endswith("-middleware")]
    volumes = {v["name"]: v for v in dep["spec"]["template"]["spec"]["volumes"]}
    assert volumes["robots"]["secret"]["secretName"] == "robot-credentials"
    assert volumes["token-key"]["secret"]["secretName"] == "middleware-token-key"
    assert "--token-key-file=/etc/netapp/token/token-key" in dep["spec"]["template"]["spec"]["containers"][0]["args"]
    # The GPU apps: a catalogue spec with the device settings is a NetApp the CRD takes and the operator renders.
    [cm] = _by_kind(objects, "ConfigMap")
    catalogue = yaml.safe_load(cm["data"]["catalogue.yaml"])
    trt = catalogue["apps"]["object-detection-tensorrt"]["spec"]
    jsonschema.validate(
        {"apiVersion": "netapp.dev/v1alpha1", "kind": "NetApp", "metadata": {"name": "x"}, "spec": trt},
        CRD_SCHEMAS["NetApp"],
    )
    spec = parse(trt)
    assert spec.problems == () and spec.requires_gpu and spec.trt_cache.claim_name == "tensorrt-engines"


def test_the_chart_draws_a_token_key_once_and_keeps_it(helm):
    import base64

    [secret] = [s for s in _by_kind(template(helm), "Secret") if s["metadata"]["name"].endswith("-token-key")]
    assert len(base64.b64decode(secret["data"]["token-key"])) >= 32  # what the middleware accepts
    chart = (CHART / "templates" / "middleware-token-key.yaml").read_text()
    assert 'lookup "v1" "Secret"' in chart  # helm upgrade keeps the installed key
    [dep] = [d for d in _by_kind(template(helm), "Deployment") if d["metadata"]["name"].endswith("-middleware")]
    volumes = {v["name"]: v for v in dep["spec"]["template"]["spec"]["volumes"]}
    assert volumes["token-key"]["secret"]["secretName"] == secret["metadata"]["name"]


def test_network_policies_admit_only_what_the_control_plane_serves(helm, tmp_path):
    policies = {p["metadata"]["name"]: p["spec"] for p in _by_kind(template(helm), "NetworkPolicy")}
    middleware, operator = policies["netapp-toolkit-middleware"], policies["netapp-toolkit-operator"]
    assert middleware["podSelector"]["matchLabels"]["app.kubernetes.io/name"] == "netapp-middleware"
    assert middleware["ingress"] == [{"ports": [{"port": "http", "protocol": "TCP"}]}]
    # the operator serves robots only its waker (a sleeping NetApp's Service sends them there: waker.py)
    assert operator["ingress"] == [{"ports": [{"port": "waker", "protocol": "TCP"}]}]
    assert operator["policyTypes"] == ["Ingress"]
    [op] = [d for d in _by_kind(template(helm), "Deployment") if d["metadata"]["name"].endswith("-operator")]
    [waker] = op["spec"]["template"]["spec"]["containers"]
    assert {"name": "waker", "containerPort": 8083, "protocol": "TCP"} in waker["ports"] and "--waker-port=8083" in (
        waker["args"]
    )
    assert {"name": "POD_IP", "valueFrom": {"fieldRef": {"fieldPath": "status.podIP"}}} in waker["env"]
    [dep] = [d for d in _by_kind(template(helm), "Deployment") if d["metadata"]["name"].endswith("-middleware")]
    [container] = dep["spec"]["template"]["spec"]["containers"]
    assert {"name": "http", "containerPort": 8080, "protocol": "TCP"} in container["ports"]  # the port admitted
    off = tmp_path / "off.yaml"
    off.write_text("networkPolicy: {enabled: false}\n")
    assert not _by_kind(template(helm, off), "NetworkPolicy")


def test_the_middleware_runs_as_exactly_one_replica(helm):
    objects = template(helm)
    [dep] = [d for d in _by_kind(objects, "Deployment") if d["metadata"]["name"].endswith("-middleware")]
    assert dep["spec"]["replicas"] == 1 and dep["spec"]["strategy"] == {"type": "Recreate"}


@pytest.mark.parametrize(
    "values, message",
    [
        ("nodePools: [{name: edge, type: fog, nodeSelector: {a: b}}]", "/nodePools/0/type"),
        ("nodePools: [{name: Edge_1, type: edge, nodeSelector: {a: b}}]", "/nodePools/0/name"),
        ("nodePools: [{name: edge, type: edge}]", "missing property 'nodeSelector'"),
        ("middleware: {service: {type: Ingress}}", "/middleware/service/type"),
        ("middleware: {replicas: 3}", "additional properties 'replicas' not allowed"),
        ("robots: {items: [{id: r1}]}", "missing property 'secretHash'"),
        ("robots: {items: [{id: r1, secretHash: plain-text-secret}]}", "/robots/items/0/secretHash"),
        ("catalogue: {detector: {description: no spec}}", "missing property 'spec'"),
        ("catalogue: {gpu: {spec: {image: i, device: tpu}}}", "/catalogue/gpu/spec/device"),
        ("middleware: {ingress: {enabled: true, tls: {enabled: true}}}", "/middleware/ingress/tls/secretName"),
        ("operator: {failoverGraceSeconds: -1}", "/operator/failoverGraceSeconds"),
        ("operatr: {enabled: true}", "additional properties 'operatr' not allowed"),
    ],
)
def test_values_schema_rejects_bad_values(helm, tmp_path, values, message):
    path = tmp_path / "values.yaml"
    path.write_text(values + "\n")
    result = run(helm, "template", "x", CHART, "--values", path, check=False)
    assert result.returncode != 0
    assert "values don't meet the specifications of the schema" in result.stderr
    assert message in result.stderr, result.stderr


def test_notes_tell_how_to_reach_the_middleware_and_apply_a_netapp(helm, tmp_path):
    result = run(
        helm,
        "install",
        "netapp-toolkit",
        CHART,
        "--dry-run=client",
        "--namespace",
        "netapp-system",
        "--kubeconfig",
        tmp_path / "none",
    )
    notes = result.stdout.split("NOTES:", 1)[1]
    assert "port-forward service/netapp-toolkit-middleware" in notes
    assert "kind: NetApp" in notes and "kubectl -n netapp-system get netapp detector" in notes


def test_manifests_are_rendered_from_the_chart(helm):
    """manifests/ must be exactly what `make manifests` renders from the chart (one source of truth)."""
    from tools.render_manifests import render

    for name, text in render(helm).items():
        path = ROOT / "manifests" / name
        assert path.exists() and path.read_text() == text, f"manifests/{name} drifted: run `make manifests`"
    generated = {p.name for p in (ROOT / "manifests").glob("*.yaml")}
    assert generated == set(render(helm)), "a hand-written file sits at the top of manifests/"


def test_kubectl_apply_and_helm_install_create_the_same_objects(helm):
    """`kubectl apply -f manifests/` creates exactly the objects `helm install --create-namespace` creates."""

    def key(o: dict) -> tuple:
        return o["kind"], o["metadata"].get("namespace"), o["metadata"]["name"]

    from_helm = {key(o): o for o in template(helm)}
    # The token key Secret is drawn at install time: kubectl users create it by hand
    # (docs/kubernetes.md#plain-kubectl), under this name.
    token_key = from_helm.pop(("Secret", "netapp-system", "netapp-toolkit-middleware-token-key"))
    assert token_key["metadata"]["annotations"]["helm.sh/resource-policy"] == "keep"
    rollout_token = from_helm.pop(("Secret", "netapp-system", "netapp-toolkit-operator-rollout-token"))  # the same
    assert rollout_token["metadata"]["annotations"]["helm.sh/resource-policy"] == "keep"
    applied = {}
    for path in sorted((ROOT / "manifests").glob("*.yaml")):
        applied |= {key(d): d for d in yaml.safe_load_all(path.read_text()) if d}
    namespace = applied.pop(("Namespace", None, "netapp-system"))  # helm's --create-namespace makes this one
    assert namespace["metadata"]["labels"]["pod-security.kubernetes.io/enforce"] == "restricted"
    assert applied == from_helm
