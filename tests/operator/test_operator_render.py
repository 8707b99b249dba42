"""Pure rendering of a NetApp's children: contract labels, security, probes, placement, model, autoscaling, URL."""

from __future__ import annotations

import base64
import copy

import pytest
from netapp_operator import render as renderer
from netapp_operator.config import OperatorConfig
from netapp_operator.placement import Pool
from netapp_operator.render import child_name
from netapp_operator.spec import parse
from netapp_operator.status import service_url as observed_url

UID = "0b3f6d2e-0000-4000-8000-000000000001"


def netapp(**spec) -> dict:
    spec.setdefault("image", "ghcr.io/netapp-toolkit/netapp:0.1.0")
    return {
        "apiVersion": "netapp.dev/v1alpha1",
        "kind": "NetApp",
        "metadata": {"name": "det", "namespace": "robots", "uid": UID, "generation": 1},
        "spec": spec,
    }


def pool(name: str = "edge", **spec) -> Pool:
    spec.setdefault("nodeSelector", {"netapp.dev/pool": name})
    spec.setdefault("type", "edge")
    return Pool(
        name=name,
        type=spec["type"],
        gpu=bool(spec.get("gpu")),
        priority=0,
        spec=spec,
        ready_nodes=1,
        total_nodes=1,
        addresses=("192.168.1.10",),
    )


def render(na: dict, p: Pool, config: OperatorConfig | None = None) -> list[dict]:
    return renderer.render(na, parse(na["spec"]), p, config)


def service_url(na: dict, p: Pool, service: dict | None) -> str | None:
    return observed_url(na, parse(na["spec"]), p, service)


def kinds(manifests: list[dict]) -> dict[str, dict]:
    return {m["kind"]: m for m in manifests}


def test_children_carry_contract_labels_and_owner_reference():
    for m in render(netapp(), pool()):
        assert m["metadata"]["name"] == "det-edge" and m["metadata"]["namespace"] == "robots"
        assert m["metadata"]["labels"] == {
            "app.kubernetes.io/name": "netapp",
            "app.kubernetes.io/instance": "det",
            "app.kubernetes.io/managed-by": "netapp-operator",
            "netapp.dev/pool": "edge",
        }
        [ref] = m["metadata"]["ownerReferences"]
        assert ref == {
            "apiVersion": "netapp.dev/v1alpha1",
            "kind": "NetApp",
            "name": "det",
            "uid": UID,
            "controller": True,
            "blockOwnerDeletion": True,
        }


def test_deployment_is_locked_down_and_probed():
    dep = kinds(render(netapp(), pool()))["Deployment"]
    pod = dep["spec"]["template"]["spec"]
    assert pod["securityContext"]["runAsNonRoot"] is True
    assert pod["securityContext"]["seccompProfile"] == {"type": "RuntimeDefault"}
    assert pod["automountServiceAccountToken"] is False
    [c] = pod["containers"]
    sc = c["securityContext"]
    assert (
        sc["readOnlyRootFilesystem"] and not sc["allowPrivilegeEscalation"] and sc["capabilities"] == {"drop": ["ALL"]}
    )
    assert c["livenessProbe"]["httpGet"] == {"path": "/healthz", "port": "http"}
    assert c["readinessProbe"]["httpGet"] == {"path": "/readyz", "port": "http"}
    assert c["ports"] == [{"name": "http", "containerPort": 5896, "protocol": "TCP"}]
    # The server needs --model: a NetApp without one gets the operator's default, fetched and checked.
    assert c["args"][:6] == ["--model", "/models/model.onnx", "--host", "0.0.0.0", "--port", "5896"]
    env = {e["name"]: e["value"] for e in pod["initContainers"][0]["env"]}
    assert env["MODEL_URL"].endswith("yolox_nano.onnx") and len(env["MODEL_SHA256"]) == 64
    assert {"name": "tmp", "mountPath": "/tmp"} in c["volumeMounts"]
    assert dep["spec"]["replicas"] == 1
    assert dep["spec"]["template"]["metadata"]["labels"]["netapp.dev/pool"] == "edge"


def test_resources_and_gpus():
    c = kinds(render(netapp(resources={"cpu": "2", "memory": "1Gi", "gpus": 2}, port=8000), pool(gpu=True)))[
        "Deployment"
    ]["spec"]["template"]["spec"]["containers"][0]
    assert c["resources"] == {
        "requests": {"cpu": "2", "memory": "1Gi", "nvidia.com/gpu": 2},
        "limits": {"memory": "1Gi", "nvidia.com/gpu": 2},
    }
    assert c["args"][c["args"].index("--port") + 1] == "8000"


def test_spec_device_fp16_and_engine_cache_reach_the_netapps_args_and_volumes():
    def pod(na: dict) -> dict:
        return kinds(render(na, pool(gpu=True)))["Deployment"]["spec"]["template"]["spec"]

    plain = pod(netapp())["containers"][0]
    assert not {"--device", "--fp16", "--trt-cache"} & set(plain["args"])  # auto is the netapp's own default
    assert "nvidia.com/gpu" not in plain["resources"]["requests"]

    cuda = pod(netapp(device="cuda"))["containers"][0]
    assert cuda["args"][cuda["args"].index("--device") + 1] == "cuda" and "--trt-cache" not in cuda["args"]
    assert cuda["resources"]["requests"]["nvidia.com/gpu"] == 1 == cuda["resources"]["limits"]["nvidia.com/gpu"]

    trt = pod(netapp(device="tensorrt", fp16=True))
    args = trt["containers"][0]["args"]
    assert args[args.index("--device") + 1] == "tensorrt" and "--fp16" in args
    assert args[args.index("--trt-cache") + 1] == "/var/cache/netapp/tensorrt"
    volumes = {v["name"]: v for v in trt["volumes"]}
    assert volumes["trt-cache"] == {"name": "trt-cache", "emptyDir": {"sizeLimit": "2Gi"}}
    mounts = {m["name"]: m for m in trt["containers"][0]["volumeMounts"]}
    assert mounts["trt-cache"]["mountPath"] == "/var/cache/netapp/tensorrt" and not mounts["trt-cache"].get("readOnly")
    assert {"key": "nvidia.com/gpu", "operator": "Exists", "effect": "NoSchedule"} in trt["tolerations"]

    kept = pod(netapp(device="tensorrt", engineCache={"claimName": "engines"}))
    [volume] = [v for v in kept["volumes"] if v["name"] == "trt-cache"]
    assert volume == {"name": "trt-cache", "persistentVolumeClaim": {"claimName": "engines"}}


def test_pool_placement_is_copied_into_the_pod():
    p = pool(
        "cloud",
        type="cloud",
        tolerations=[{"key": "cloud", "operator": "Exists", "effect": "NoSchedule"}],
        affinity={"nodeAffinity": {"preferredDuringSchedulingIgnoredDuringExecution": []}},
    )
    pod = kinds(render(netapp(resources={"gpus": 1}), p))["Deployment"]["spec"]["template"]["spec"]
    assert pod["nodeSelector"] == {"netapp.dev/pool": "cloud"}
    assert pod["affinity"] == p.spec["affinity"]
    assert [t["key"] for t in pod["tolerations"]] == ["cloud", "nvidia.com/gpu"]


def test_model_url_is_fetched_by_a_bounded_checked_init_container():
    sha = "ab" * 32
    pod = kinds(
        render(
            netapp(model={"url": "https://models.example.com/y.onnx", "sha256": sha, "timeoutSeconds": 60}),
            pool(),
            OperatorConfig(model_init_image="curl:x", model_cache_dir=""),  # no node cache (its own test below)
        )
    )["Deployment"]["spec"]["template"]["spec"]
    [init] = pod["initContainers"]
    env = {e["name"]: e["value"] for e in init["env"]}
    assert env == {
        "MODEL_URL": "https://models.example.com/y.onnx",
        "MODEL_SHA256": sha,
        "MODEL_TIMEOUT": "60",
        "MODEL_PATH": "/models/model.onnx",
    }
    assert init["image"] == "curl:x" and "--max-time" in init["command"][-1] and "sha256sum -c" in init["command"][-1]
    assert init["securityContext"]["readOnlyRootFilesystem"] is True
    assert {"name": "model", "emptyDir": {}} in pod["volumes"]
    assert pod["containers"][0]["args"][:2] == ["--model", "/models/model.onnx"]


def test_no_default_model_means_no_model_argument():
    dep = kinds(render(netapp(), pool(), OperatorConfig(default_model_url="")))["Deployment"]
    pod = dep["spec"]["template"]["spec"]
    assert "initContainers" not in pod and pod["containers"][0]["args"][:4] == ["--host", "0.0.0.0", "--port", "5896"]


def test_model_volume_mounts_the_claim_read_only():
    pod = kinds(render(netapp(model={"volume": {"claimName": "models", "path": "yolox/nano.onnx"}}), pool()))[
        "Deployment"
    ]["spec"]["template"]["spec"]
    assert "initContainers" not in pod
    assert {"name": "model", "persistentVolumeClaim": {"claimName": "models", "readOnly": True}} in pod["volumes"]
    assert pod["containers"][0]["args"][:2] == ["--model", "/models/yolox/nano.onnx"]


def test_state_volume_is_the_writable_state_dir():
    pod = kinds(render(netapp(state={"volume": {"claimName": "states"}}), pool()))["Deployment"]["spec"]["template"][
        "spec"
    ]
    assert {"name": "state", "persistentVolumeClaim": {"claimName": "states"}} in pod["volumes"]
    container = pod["containers"][0]
    assert {"name": "state", "mountPath": "/var/lib/netapp/state"} in container["volumeMounts"]
    args = container["args"]
    assert args[args.index("--state-dir") + 1] == "/var/lib/netapp/state"


def test_autoscaling_adds_an_hpa_and_leaves_replicas_to_it():
    out = kinds(render(netapp(autoscaling={"minReplicas": 2, "maxReplicas": 5}), pool()))
    assert "replicas" not in out["Deployment"]["spec"]
    hpa = out["HorizontalPodAutoscaler"]
    assert hpa["spec"]["scaleTargetRef"] == {"apiVersion": "apps/v1", "kind": "Deployment", "name": "det-edge"}
    assert (hpa["spec"]["minReplicas"], hpa["spec"]["maxReplicas"]) == (2, 5)
    assert hpa["spec"]["metrics"][0]["resource"]["target"]["averageUtilization"] == 70


def test_service_type_comes_from_the_pool():
    svc = kinds(render(netapp(), pool(access={"serviceType": "LoadBalancer"})))["Service"]
    assert svc["spec"]["type"] == "LoadBalancer"
    assert svc["spec"]["ports"] == [{"name": "http", "port": 5896, "targetPort": "http", "protocol": "TCP"}]
    assert svc["spec"]["selector"] == {
        "app.kubernetes.io/name": "netapp",
        "app.kubernetes.io/instance": "det",
        "netapp.dev/pool": "edge",
    }


def test_render_is_pure():
    na, p = netapp(model={"url": "https://x/y.onnx"}), pool()
    before = copy.deepcopy(na)
    assert render(na, p) == render(na, p)
    assert na == before


def test_long_names_stay_valid_and_unique():
    a, b = child_name("x" * 60, "edge-one"), child_name("x" * 60, "edge-two")
    assert len(a) <= 63 and len(b) <= 63 and a != b


def _svc(node_port=None, lb=None) -> dict:
    port = {"name": "http", "port": 5896}
    if node_port:
        port["nodePort"] = node_port
    return {"spec": {"ports": [port]}, "status": {"loadBalancer": {"ingress": [lb]} if lb else {}}}


@pytest.mark.parametrize(
    "access, service, url",
    [
        ({"serviceType": "NodePort"}, _svc(31000), "http://192.168.1.10:31000"),
        ({"serviceType": "NodePort", "host": "edge.local"}, _svc(31000), "http://edge.local:31000"),
        ({"serviceType": "NodePort"}, _svc(), None),
        ({"serviceType": "LoadBalancer"}, _svc(31000, {"ip": "203.0.113.7"}), "http://203.0.113.7:5896"),
        ({"serviceType": "LoadBalancer"}, _svc(31000), None),
        ({"serviceType": "ClusterIP"}, _svc(), "http://det-edge.robots.svc.cluster.local:5896"),
        (
            {"serviceType": "ClusterIP", "urlTemplate": "https://{name}.{namespace}.edge.example.com"},
            _svc(),
            "https://det.robots.edge.example.com",
        ),
        (
            {"serviceType": "NodePort", "urlTemplate": "http://{host}:{nodePort}/{pool}"},
            _svc(30001),
            "http://192.168.1.10:30001/edge",
        ),
    ],
)
def test_service_url(access, service, url):
    assert service_url(netapp(), pool(access=access), service) == url


def test_replicas_share_a_key_advertise_their_pod_ip_and_drain_before_they_go():
    from netapp_operator.constants import DRAIN_GRACE_S, PRESTOP_SLEEP_S, TERMINATION_GRACE_S

    from netapp.protocol import ADVERTISE_URL_ENV, CLUSTER_KEY_ENV

    dep = kinds(render(netapp(port=8080, env=[{"name": "A", "value": "1"}]), pool()))["Deployment"]
    pod = dep["spec"]["template"]["spec"]
    [c] = pod["containers"]
    env = {e["name"]: e for e in c["env"]}
    assert env["POD_IP"]["valueFrom"] == {"fieldRef": {"fieldPath": "status.podIP"}}
    assert env[ADVERTISE_URL_ENV]["value"] == "http://$(POD_IP):8080"
    assert [e["name"] for e in c["env"]].index("POD_IP") < [e["name"] for e in c["env"]].index(ADVERTISE_URL_ENV)
    assert env[CLUSTER_KEY_ENV]["valueFrom"]["secretKeyRef"] == {
        "name": "det-cluster-key",
        "key": "key",
        "optional": True,
    }
    assert env["A"]["value"] == "1"
    assert c["args"][c["args"].index("--drain-grace") + 1] == str(DRAIN_GRACE_S)
    # preStop keeps serving while the endpoint leaves the Service; then the drain; all within the grace period
    assert c["lifecycle"]["preStop"]["exec"]["command"] == ["sleep", str(PRESTOP_SLEEP_S)]
    assert pod["terminationGracePeriodSeconds"] == TERMINATION_GRACE_S > PRESTOP_SLEEP_S + DRAIN_GRACE_S + 5
    # a draining replica's 503 takes it out of the Service after one probe
    assert c["readinessProbe"]["failureThreshold"] == 1 and c["readinessProbe"]["periodSeconds"] <= 2


def test_the_cluster_key_secret_is_one_per_netapp_and_owned_by_it():
    from netapp_operator.render import render_cluster_key_secret

    secret = render_cluster_key_secret(netapp(), "k" * 64)
    assert secret["metadata"]["name"] == "det-cluster-key" and secret["data"] == {
        "key": base64.b64encode(b"k" * 64).decode()
    }
    assert secret["metadata"]["ownerReferences"][0]["uid"] == UID
    assert [m for m in render(netapp(), pool()) if m["kind"] == "Secret"] == []  # made once, not on every apply


def test_a_custom_processor_gets_no_model_and_a_built_in_name_keeps_it():
    from netapp_operator.constants import DRAIN_GRACE_S

    config = OperatorConfig(default_model_url="https://models.example.com/y.onnx")
    custom = kinds(render(netapp(processor="mypkg.sharp:Sharpness"), pool(), config))["Deployment"]
    pod = custom["spec"]["template"]["spec"]
    assert "initContainers" not in pod and [v["name"] for v in pod["volumes"]] == ["tmp"]
    assert pod["containers"][0]["args"] == [
        "--processor",
        "mypkg.sharp:Sharpness",
        "--host",
        "0.0.0.0",
        "--port",
        "5896",
        "--drain-grace",
        str(DRAIN_GRACE_S),
    ]
    named = kinds(render(netapp(processor="object-detection"), pool(), config))["Deployment"]
    args = named["spec"]["template"]["spec"]["containers"][0]["args"]
    assert args[:4] == ["--processor", "object-detection", "--model", "/models/model.onnx"]


def test_spec_admission_measured_reaches_the_netapps_args():
    def args(na: dict) -> list[str]:
        return kinds(render(na, pool()))["Deployment"]["spec"]["template"]["spec"]["containers"][0]["args"]

    measured = args(netapp(admission="measured"))
    assert measured[measured.index("--admission") + 1] == "measured"
    assert "--admission" not in args(netapp())  # open is the netapp's own default


def test_spec_priority_reaches_the_netapps_args():
    def args(na: dict) -> list[str]:
        return kinds(render(na, pool()))["Deployment"]["spec"]["template"]["spec"]["containers"][0]["args"]

    high, low = "a" * 64, "b" * 64
    rendered = args(netapp(priority={"robots": "low", "tokenSha256": {"high": high, "normal": low}}))
    assert rendered[rendered.index("--robot-priority") + 1] == "low"
    tokens = [rendered[i + 1] for i, a in enumerate(rendered) if a == "--priority-token"]
    assert tokens == [f"high={high}", f"normal={low}"]
    plain = args(netapp(priority={"robots": "normal"}))
    assert "--robot-priority" not in plain and "--priority-token" not in plain  # the netapp's own defaults
    assert "--priority-weights" not in plain
    weighed = args(netapp(priority={"weights": {"high": 9, "low": 0.5}}))
    assert weighed[weighed.index("--priority-weights") + 1] == "low=0.5,high=9"  # what netapp serve parses


def test_spec_priority_weights_must_be_classes_with_positive_numbers():
    from netapp_operator.spec import parse

    for weights in ({"vip": 1}, {"low": 0}, {"high": -2}, {"normal": "2"}, {"low": True}, {"low": float("inf")}):
        problems = parse({"image": "i", "priority": {"weights": weights}}).problems
        assert any("spec.priority.weights maps a class" in p for p in problems), (weights, problems)
    assert not parse({"image": "i", "priority": {"weights": {"low": 1, "high": 8.5}}}).problems


def test_a_standby_is_the_same_netapp_on_its_own_pool_labelled_never_autoscaled():
    na = netapp(replicas=3, standby={"replicas": 2}, autoscaling={"maxReplicas": 5}, resources={"cpu": "1"})
    cloud = pool("cloud", type="cloud")
    spec = parse(na["spec"])
    warm = kinds(renderer.render_standby(na, spec, cloud))
    assert set(warm) == {"Deployment", "Service", "NetworkPolicy"}  # no autoscaler: a standby waits, it does not serve
    deployment = warm["Deployment"]
    assert deployment["metadata"]["name"] == child_name("det", "cloud") and deployment["spec"]["replicas"] == 2
    assert all(m["metadata"]["labels"]["netapp.dev/role"] == "standby" for m in warm.values())
    # Its pods are the NetApp's own (not labelled standby): a failover to this pool takes them over as they are.
    own = kinds(render(na, cloud))["Deployment"]
    assert deployment["spec"]["template"] == own["spec"]["template"]
    assert deployment["spec"]["selector"] == own["spec"]["selector"]
    assert renderer.render_standby(netapp(), parse(netapp()["spec"]), cloud) == []
    assert renderer.resource_requests(spec) == {"cpu": "1", "memory": "512Mi"}


def test_spec_sources_reach_the_netapps_args_before_the_extra_args():
    def args(na: dict) -> list[str]:
        return kinds(render(na, pool()))["Deployment"]["spec"]["template"]["spec"]["containers"][0]["args"]

    rendered = args(netapp(sources=[{"name": "door", "url": "rtsp://10.0.0.5/s"}], args=["--conf", "0.5"]))
    assert rendered[-4:] == ["--source", "door=rtsp://10.0.0.5/s", "--conf", "0.5"]
    assert "--source" not in args(netapp())
