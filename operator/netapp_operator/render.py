"""Child manifests of a NetApp (pure): render(netapp, spec, pool) -> [Deployment, Service, NetworkPolicy, (HPA)],
its warm standby's on another pool (`render_standby`), and its token Secret (`render_token_secret`, created once by
the reconciler, never re-applied).

Everything the cluster gets is decided here, so it is unit-tested and schema-validated without a cluster.

The netapp's command is the one every backend runs (`serve_command`); the container adds around it only what a
cluster has, and the middleware's local backend none of it:
- flags after `--port` (`CLUSTER_ONLY_ARGS`): `--drain-grace` (the pod's SIGTERM drain, within its grace period),
  `--camera-leases` (replicas sharing cameras through Leases, with the ServiceAccount `camera_access_name`), and
  `--tls-cert` / `--tls-key` (the TLS Secret's mount);
- the environment (`CLUSTER_ONLY_ENV`): the pod's IP from the downward API, its advertised URL and the key replicas
  share (`_replica_env`), the camera Leases' NetApp and pod name, the token Secret's token, the TURN Secret's
  credentials, and the digest of the operator's rollout token;
- where the files are (`Where`): the model fetched by an init container (or a volume's) under /models, and the
  volumes of `--state-dir` and `--trt-cache`.
"""

from __future__ import annotations

import base64
import dataclasses
import hashlib
from collections.abc import Mapping
from typing import Any

from netapp.protocol import ADMIN_TOKEN_DIGEST_ENV, ADVERTISE_URL_ENV, CLUSTER_KEY_ENV, NETAPP_NAME_ENV, TOKEN_ENV
from netapp.webrtc_ice import CREDENTIAL_ENV, USERNAME_ENV
from netapp_operator import autoscaling, idle, rollouts
from netapp_operator import spec as specs
from netapp_operator.cameras import CAMERA_KINDS, camera_access_name, camera_pod, render_camera_access
from netapp_operator.config import OperatorConfig
from netapp_operator.constants import (
    ANNOTATION_MODEL,
    API_VERSION,
    CLUSTER_KEY_SECRET_KEY,
    DRAIN_GRACE_S,
    LABEL_INSTANCE,
    LABEL_MANAGED_BY,
    LABEL_NAME,
    LABEL_POOL,
    LABEL_ROLE,
    NETAPP_APP_NAME,
    NETAPP_KIND,
    OPERATOR_MANAGER,
    PRESTOP_SLEEP_S,
    READINESS_PERIOD_S,
    TERMINATION_GRACE_S,
    TLS_DIR,
    TOKEN_SECRET_KEY,
    cluster_key_secret_name,
    token_secret_name,
)
from netapp_operator.model_fetch import model_files
from netapp_operator.placement import Pool
from netapp_operator.publish import CONSUME, publish_env
from netapp_operator.rtp import container_ports, policy_ports, service_ports
from netapp_operator.serve_command import Where, serve_command
from netapp_operator.spec import NetAppSpec
from netapp_operator.webrtc import effective_webrtc, webrtc_env

Manifest = dict[str, Any]
ROLE_STANDBY = "standby"
# Ready the moment it can serve: /readyz (the model loaded and run once) asked every second, for as long as a cold
# node's model load may take (a TensorRT engine build: minutes). Once it answers, the kubelet asks the readiness
# probe at once rather than a period later, and liveness starts.
STARTUP_PROBE = {"httpGet": {"path": "/readyz", "port": "http"}, "periodSeconds": 1, "failureThreshold": 300}
CLUSTER_ONLY_ARGS = ("--drain-grace", "--camera-leases", "--tls-cert", "--tls-key")  # each with its value
CLUSTER_ONLY_ENV = (
    "POD_IP",
    ADVERTISE_URL_ENV,
    CLUSTER_KEY_ENV,
    NETAPP_NAME_ENV,
    "POD_NAME",
    TOKEN_ENV,
    USERNAME_ENV,
    CREDENTIAL_ENV,
    ADMIN_TOKEN_DIGEST_ENV,
)


def child_name(netapp: str, pool: str) -> str:
    """Children are named per pool so that a failover can start the new ones before removing the old.

    Service names must be DNS-1035 labels (63 characters); long names keep a hash to stay unique."""
    name = f"{netapp}-{pool}"
    if len(name) <= 63:
        return name
    digest = hashlib.sha256(name.encode()).hexdigest()[:8]
    return f"{name[:54].rstrip('-')}-{digest}"


def _replica_env(netapp: Mapping[str, Any], spec: NetAppSpec, port: int) -> list[dict[str, Any]]:
    """How a replica finds its own address (the downward API's pod IP) and the key it shares with the others. With
    TLS the others reach it over HTTPS, verifying it against the certificate they share (its own --tls-cert:
    docs/security.md#tls-between-replicas)."""
    secret = {"name": cluster_key_secret_name(netapp["metadata"]["name"]), "key": CLUSTER_KEY_SECRET_KEY}
    scheme = "https" if spec.tls is not None else "http"
    return [
        {"name": "POD_IP", "valueFrom": {"fieldRef": {"fieldPath": "status.podIP"}}},
        {"name": ADVERTISE_URL_ENV, "value": f"{scheme}://$(POD_IP):{port}"},
        # optional: until the operator has made the Secret, a replica runs on its own rather than not at all
        {"name": CLUSTER_KEY_ENV, "valueFrom": {"secretKeyRef": {**secret, "optional": True}}},
    ]


def labels(netapp: str, pool: str) -> dict[str, str]:
    return {
        LABEL_NAME: NETAPP_APP_NAME,
        LABEL_INSTANCE: netapp,
        LABEL_MANAGED_BY: OPERATOR_MANAGER,
        LABEL_POOL: pool,
    }


def owner_reference(netapp: Mapping[str, Any]) -> dict[str, Any]:
    meta = netapp["metadata"]
    return {
        "apiVersion": API_VERSION,
        "kind": NETAPP_KIND,
        "name": meta["name"],
        "uid": meta["uid"],
        "controller": True,
        "blockOwnerDeletion": True,
    }


def _metadata(netapp: Mapping[str, Any], pool: Pool) -> dict[str, Any]:
    meta = netapp["metadata"]
    return {
        "name": child_name(meta["name"], pool.name),
        "namespace": meta["namespace"],
        "labels": labels(meta["name"], pool.name),
        "ownerReferences": [owner_reference(netapp)],
    }


def resource_requests(spec: NetAppSpec) -> dict[str, Any]:
    """What each replica requests: CPU, memory and GPUs (what a standby costs, per replica)."""
    res = spec.resources
    requests: dict[str, Any] = {"cpu": res.cpu or "250m", "memory": res.memory or "512Mi"}
    if spec.gpus:
        requests["nvidia.com/gpu"] = spec.gpus
    return requests


def _resources(spec: NetAppSpec) -> dict[str, Any]:
    requests = resource_requests(spec)
    # No CPU limit: throttling a latency-bound inference server costs more than it protects.
    limits: dict[str, Any] = {"memory": requests["memory"]}
    if spec.gpus:
        limits["nvidia.com/gpu"] = spec.gpus
    return {"requests": requests, "limits": limits}


def served_model(spec: NetAppSpec, config: OperatorConfig) -> dict[str, Any] | None:
    """The model `_model` renders, as `status.model` records it."""
    model = spec.model
    if spec.custom_processor or (model is None and not config.default_model_url):
        return None
    if model is None:
        return rollouts.wanted_model({}, config.default_model_url, config.default_model_sha256)
    if model.has_volume:
        return {"volume": {"claimName": model.volume_claim, "path": model.volume_path}}
    return {"url": model.url, **({"sha256": model.sha256.lower()} if model.sha256 else {})}


def _state(spec: NetAppSpec) -> tuple[list[dict], list[dict]]:
    """(volumes, mounts) for saved session states: the claim, writable, at the `--state-dir` (`Where.state_dir`)."""
    if spec.state is None:
        return [], []
    claim = spec.state.volume_claim
    return (
        [{"name": "state", "persistentVolumeClaim": {"claimName": claim}}],
        [{"name": "state", "mountPath": specs.STATE_DIR}],
    )


def _engine_cache(spec: NetAppSpec) -> tuple[list[dict], list[dict]]:
    """(volumes, mounts) for TensorRT's engine cache, a PVC or an emptyDir, writable, at `--trt-cache`."""
    cache = spec.trt_cache
    if cache is None:
        return [], []
    if cache.claim_name:
        volume = {"name": "trt-cache", "persistentVolumeClaim": {"claimName": cache.claim_name}}
    else:
        volume = {"name": "trt-cache", "emptyDir": {"sizeLimit": str(cache.size_limit)}}
    return [volume], [{"name": "trt-cache", "mountPath": specs.ENGINE_CACHE_DIR}]


def _container_security() -> dict[str, Any]:
    return {
        "allowPrivilegeEscalation": False,
        "readOnlyRootFilesystem": True,
        "runAsNonRoot": True,
        "capabilities": {"drop": ["ALL"]},
        "seccompProfile": {"type": "RuntimeDefault"},
    }


def _tolerations(spec: NetAppSpec, pool: Pool) -> list[dict[str, Any]]:
    tolerations = [dict(t) for t in pool.spec.get("tolerations", []) or []]
    if spec.gpus and not any(t.get("key") == "nvidia.com/gpu" for t in tolerations):
        # GPU nodes are commonly tainted nvidia.com/gpu:NoSchedule to keep other pods off them.
        tolerations.append({"key": "nvidia.com/gpu", "operator": "Exists", "effect": "NoSchedule"})
    return tolerations


def render_deployment(netapp: Mapping[str, Any], spec: NetAppSpec, pool: Pool, config: OperatorConfig) -> Manifest:
    meta = _metadata(netapp, pool)
    port = int(spec.port)
    model_file, init_containers, volumes, mounts = model_files(spec, config, _container_security())
    state_volumes, state_mounts = _state(spec)
    cache_volumes, cache_mounts = _engine_cache(spec)
    volumes, mounts = [*volumes, *state_volumes, *cache_volumes], [*mounts, *state_mounts, *cache_mounts]
    camera_args, camera_env = camera_pod(netapp, spec.sources)
    webrtc = effective_webrtc(spec.webrtc, config.default_webrtc)
    tls_args = ("--tls-cert", f"{TLS_DIR}/tls.crt", "--tls-key", f"{TLS_DIR}/tls.key") if spec.tls is not None else ()
    where = Where(
        host="0.0.0.0",
        port=port,
        model_file=model_file,
        runtime_args=("--drain-grace", str(DRAIN_GRACE_S), *camera_args, *tls_args),
    )
    command = serve_command(spec, where, webrtc)
    container = {
        "name": "netapp",
        "image": spec.image,
        "imagePullPolicy": "IfNotPresent",
        "args": command.args,
        "env": [
            *_replica_env(netapp, spec, port),
            *webrtc_env(webrtc),
            *publish_env(spec.publish),
            *publish_env(spec.consume, CONSUME),
            *camera_env,
            *[{"name": name, "value": value} for name, value in command.env.items()],
        ],
        "ports": [{"name": "http", "containerPort": port, "protocol": "TCP"}, *container_ports(spec.rtp)],
        "resources": _resources(spec),
        "securityContext": _container_security(),
        "startupProbe": STARTUP_PROBE,
        "livenessProbe": {
            "httpGet": {"path": "/healthz", "port": "http"},
            "periodSeconds": 10,
            "timeoutSeconds": 2,
            "failureThreshold": 3,
        },
        # A draining replica answers 503 at once: one failed probe takes it out of the Service.
        "readinessProbe": {
            "httpGet": {"path": "/readyz", "port": "http"},
            "periodSeconds": READINESS_PERIOD_S,
            "timeoutSeconds": 2,
            "failureThreshold": 1,
        },
        # Going away: keep serving while the endpoint leaves the Service, then SIGTERM drains (robots move).
        "lifecycle": {"preStop": {"exec": {"command": ["sleep", str(PRESTOP_SLEEP_S)]}}},
        # A read-only root file system still needs somewhere for temporary files.
        "volumeMounts": [{"name": "tmp", "mountPath": "/tmp"}, *mounts],
    }
    _add_access(container, netapp, spec)
    if config.rollout_token:  # the operator may start rollouts on it (docs/rollouts.md#kubernetes)
        digest = rollouts.token_digest(config.rollout_token)
        container["env"] = [*container["env"], {"name": ADMIN_TOKEN_DIGEST_ENV, "value": digest}]
        meta["annotations"] = {ANNOTATION_MODEL: rollouts.model_key(served_model(spec, config))}
    pod_spec: dict[str, Any] = {
        # only a netapp with cameras speaks to the API server (its Leases), with an account of its own
        "automountServiceAccountToken": bool(camera_args),
        "enableServiceLinks": False,
        "securityContext": {
            "runAsNonRoot": True,
            "runAsUser": config.run_as_user,
            "runAsGroup": config.run_as_user,
            "fsGroup": config.run_as_user,
            "seccompProfile": {"type": "RuntimeDefault"},
        },
        "nodeSelector": dict(pool.spec.get("nodeSelector", {})),
        "terminationGracePeriodSeconds": TERMINATION_GRACE_S,
        "containers": [container],
        "volumes": [{"name": "tmp", "emptyDir": {"sizeLimit": "256Mi"}}, *volumes, *_tls_volumes(spec)],
    }
    if camera_args:
        pod_spec["serviceAccountName"] = camera_access_name(netapp["metadata"]["name"])
    if init_containers:
        pod_spec["initContainers"] = init_containers
    tolerations = _tolerations(spec, pool)
    if tolerations:
        pod_spec["tolerations"] = tolerations
    if pool.spec.get("affinity"):
        pod_spec["affinity"] = dict(pool.spec["affinity"])
    selector = {k: meta["labels"][k] for k in (LABEL_NAME, LABEL_INSTANCE, LABEL_POOL)}
    deployment_spec: dict[str, Any] = {
        "selector": {"matchLabels": selector},
        "revisionHistoryLimit": 3,
        "strategy": {"type": "RollingUpdate", "rollingUpdate": {"maxUnavailable": 0, "maxSurge": 1}},
        "template": {"metadata": {"labels": dict(meta["labels"]), "annotations": _scrape(spec)}, "spec": pod_spec},
    }
    # With autoscaling the HPA owns the replica count; writing it here would fight the HPA on every patch.
    if spec.autoscaling is None:  # none while it sleeps (spec.scaling.idleToZero)
        deployment_spec["replicas"] = int(idle.wanted_replicas(netapp, spec.replicas))
    return {"apiVersion": "apps/v1", "kind": "Deployment", "metadata": meta, "spec": deployment_spec}


def render_service(netapp: Mapping[str, Any], spec: NetAppSpec, pool: Pool) -> Manifest:
    meta = _metadata(netapp, pool)
    service_type = (pool.spec.get("access") or {}).get("serviceType", "NodePort")
    selector = {k: meta["labels"][k] for k in (LABEL_NAME, LABEL_INSTANCE, LABEL_POOL)}
    return {
        "apiVersion": "v1",
        "kind": "Service",
        "metadata": meta,
        "spec": {
            "type": service_type,
            "selector": selector,
            "ports": [
                {"name": "http", "port": int(spec.port), "targetPort": "http", "protocol": "TCP"},
                *service_ports(spec.rtp, service_type),
            ],
        },
    }


# --- access: the token, TLS and the NetworkPolicy ------------------------------------------------------------------


def _made_once_secret(netapp: Mapping[str, Any], name: str, key: str, value: str) -> Manifest:
    """A Secret of a NetApp that the reconciler makes once (a fresh random value), owned by the NetApp so that it
    goes with it, and never applies again, so that no reconcile rotates what robots or replicas hold."""
    meta = netapp["metadata"]
    return {
        "apiVersion": "v1",
        "kind": "Secret",
        "type": "Opaque",
        "metadata": {
            "name": name,
            "namespace": meta["namespace"],
            "labels": {LABEL_NAME: NETAPP_APP_NAME, LABEL_INSTANCE: meta["name"], LABEL_MANAGED_BY: OPERATOR_MANAGER},
            "ownerReferences": [owner_reference(netapp)],
        },
        "data": {key: base64.b64encode(value.encode()).decode()},
    }


def render_token_secret(netapp: Mapping[str, Any], token: str) -> Manifest:
    """The NetApp's token Secret (`_made_once_secret`)."""
    return _made_once_secret(netapp, token_secret_name(netapp["metadata"]["name"]), TOKEN_SECRET_KEY, token)


def render_cluster_key_secret(netapp: Mapping[str, Any], key: str) -> Manifest:
    """The key the NetApp's replicas share (`_made_once_secret`): a new key would end every robot's session."""
    name = cluster_key_secret_name(netapp["metadata"]["name"])
    return _made_once_secret(netapp, name, CLUSTER_KEY_SECRET_KEY, key)


def _add_access(container: dict[str, Any], netapp: Mapping[str, Any], spec: NetAppSpec) -> None:
    """The token (from the Secret, as NETAPP_TOKEN) when the NetApp requires one; the certificate's mount with TLS
    (its flags are `Where.runtime_args`), and probes that speak HTTPS then."""
    if spec.access.require_token:
        secret = token_secret_name(netapp["metadata"]["name"])
        ref = {"secretKeyRef": {"name": secret, "key": TOKEN_SECRET_KEY}}
        container["env"] = [*container["env"], {"name": TOKEN_ENV, "valueFrom": ref}]
    if spec.tls is not None:
        mount = {"name": "tls", "mountPath": TLS_DIR, "readOnly": True}
        container["volumeMounts"] = [*container["volumeMounts"], mount]
        for probe in ("startupProbe", "livenessProbe", "readinessProbe"):  # new dicts: the probes may be constants
            container[probe] = {**container[probe], "httpGet": {**container[probe]["httpGet"], "scheme": "HTTPS"}}


def _tls_volumes(spec: NetAppSpec) -> list[dict[str, Any]]:
    if spec.tls is None:
        return []
    return [{"name": "tls", "secret": {"secretName": spec.tls.secret_name, "defaultMode": 0o440}}]


def render_network_policy(netapp: Mapping[str, Any], spec: NetAppSpec, pool: Pool) -> Manifest:
    """Only the netapp's port reaches its pods (from anywhere: robots come from outside the cluster); nothing
    else it might listen on does. Enforced where the cluster's network plugin implements NetworkPolicies."""
    meta = _metadata(netapp, pool)
    selector = {k: meta["labels"][k] for k in (LABEL_NAME, LABEL_INSTANCE, LABEL_POOL)}
    return {
        "apiVersion": "networking.k8s.io/v1",
        "kind": "NetworkPolicy",
        "metadata": meta,
        "spec": {
            "podSelector": {"matchLabels": selector},
            "policyTypes": ["Ingress"],
            "ingress": [{"ports": [{"port": int(spec.port), "protocol": "TCP"}, *policy_ports(spec.rtp)]}],
        },
    }


def _scrape(spec: NetAppSpec) -> dict[str, str]:
    """The common Prometheus annotations: scrape every netapp's /metrics (capacity, robots, queue, latency), over
    HTTPS with `spec.tls` (the chart's PodMonitor tells the two apart by `prometheus.io/scheme`)."""
    scheme = {"prometheus.io/scheme": "https"} if spec.tls is not None else {}
    return {
        "prometheus.io/scrape": "true",
        "prometheus.io/port": str(spec.port),
        "prometheus.io/path": "/metrics",
        **scheme,
    }


def render_autoscaler(netapp: Mapping[str, Any], spec: NetAppSpec, pool: Pool) -> Manifest | None:
    """The HPA or KEDA ScaledObject of `spec.autoscaling` (netapp_operator.autoscaling), None without one."""
    if spec.autoscaling is None:
        return None
    meta = _metadata(netapp, pool)
    return autoscaling.render_autoscaler(meta, meta["name"], spec.autoscaling)


def render(
    netapp: Mapping[str, Any], spec: NetAppSpec, pool: Pool, config: OperatorConfig | None = None
) -> list[Manifest]:
    """All children of a NetApp (its parsed, valid spec) placed on a pool, in the order they should be applied."""
    config = config or OperatorConfig()
    children = [
        render_deployment(netapp, spec, pool, config),
        render_service(netapp, spec, pool),
        render_network_policy(netapp, spec, pool),
    ]
    autoscaler = render_autoscaler(netapp, spec, pool)
    if autoscaler is not None:
        children.append(autoscaler)
    return [*children, *render_camera_access(netapp, spec.sources, owner_reference(netapp))]


def render_standby(
    netapp: Mapping[str, Any], spec: NetAppSpec, pool: Pool, config: OperatorConfig | None = None
) -> list[Manifest]:
    """The children of a NetApp's warm standby on `pool` (`spec.standby`): the same netapp, `standby.replicas` of it,
    never autoscaled, labelled netapp.dev/role=standby (not its pods: were the NetApp to fail over to this pool, its
    own children take these over, pods and all)."""
    if spec.standby is None:
        return []
    warm = dataclasses.replace(spec, replicas=spec.standby.replicas, autoscaling=None)
    # the camera access objects are the NetApp's, not a pool's: render() made them, the standby shares them
    children = [c for c in render(netapp, warm, pool, config) if c["kind"] not in CAMERA_KINDS]
    for child in children:
        child["metadata"]["labels"][LABEL_ROLE] = ROLE_STANDBY
    return children
