"""Pools that pull the netapp image on their nodes before any netapp needs it.

A NodePool with `spec.prePull` gets a DaemonSet (in the operator's namespace, owned by the NodePool) on its nodes:
its init containers are the images to pull (`prePull.images`, the netapp image by default), each running `sh -c
"exit 0"`, and its one container the pause image, which holds the pod (and so the images, which the kubelet does
not collect while a pod uses them) at a few hundred kilobytes of memory. A netapp's first pod on such a node starts
without waiting for its image: on a fresh node, that is most of a cold start (docs/kubernetes.md#start-up-time).
`render_prepull` is pure; `PrePull.sync` applies it, or deletes the DaemonSet of a pool that no longer asks.
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from netapp_operator.config import OperatorConfig
from netapp_operator.constants import (
    API_VERSION,
    LABEL_MANAGED_BY,
    LABEL_NAME,
    LABEL_POOL,
    NETAPP_IMAGE,
    OPERATOR_MANAGER,
    SERVICE_ACCOUNT_NAMESPACE_FILE,
)

log = logging.getLogger(__name__)

PAUSE_IMAGE = "registry.k8s.io/pause:3.10"
PREPULL_APP = "netapp-prepull"
Manifest = dict[str, Any]


def prepull_name(pool: str) -> str:
    """The DaemonSet's name: the pool's, prefixed, cut to 63 characters with a hash to keep it unique."""
    name = f"{PREPULL_APP}-{pool}"
    if len(name) <= 63:
        return name
    return f"{name[:54]}-{hashlib.sha256(pool.encode()).hexdigest()[:8]}"


def wanted_images(pool: Mapping[str, Any]) -> list[str]:
    """The images a NodePool asks its nodes to hold ([] when it asks for none)."""
    ask = (pool.get("spec") or {}).get("prePull")
    if not isinstance(ask, Mapping):
        return []
    return list(dict.fromkeys(ask.get("images") or [NETAPP_IMAGE]))


def render_prepull(pool: Mapping[str, Any], namespace: str, config: OperatorConfig) -> Manifest | None:
    """The DaemonSet that holds the pool's images on its nodes, or None when the pool asks for none."""
    images = wanted_images(pool)
    if not images:
        return None
    meta, spec = pool["metadata"], pool["spec"]
    labels = {LABEL_NAME: PREPULL_APP, LABEL_POOL: meta["name"], LABEL_MANAGED_BY: OPERATOR_MANAGER}
    security = {
        "allowPrivilegeEscalation": False,
        "readOnlyRootFilesystem": True,
        "runAsNonRoot": True,
        "capabilities": {"drop": ["ALL"]},
        "seccompProfile": {"type": "RuntimeDefault"},
    }
    small = {"requests": {"cpu": "1m", "memory": "8Mi"}, "limits": {"memory": "32Mi"}}
    pulls = [
        {
            "name": f"pull-{i}",
            "image": image,
            "imagePullPolicy": "IfNotPresent",
            "command": ["sh", "-c", "exit 0"],
            "resources": small,
            "securityContext": security,
        }
        for i, image in enumerate(images)
    ]
    tolerations = [dict(t) for t in spec.get("tolerations", []) or []]
    if spec.get("gpu") and not any(t.get("key") == "nvidia.com/gpu" for t in tolerations):
        tolerations.append({"key": "nvidia.com/gpu", "operator": "Exists", "effect": "NoSchedule"})
    pod: dict[str, Any] = {
        "automountServiceAccountToken": False,
        "enableServiceLinks": False,
        "securityContext": {
            "runAsNonRoot": True,
            "runAsUser": config.run_as_user,
            "runAsGroup": config.run_as_user,
            "seccompProfile": {"type": "RuntimeDefault"},
        },
        "nodeSelector": dict(spec.get("nodeSelector", {})),
        "initContainers": pulls,
        "containers": [{"name": "hold", "image": PAUSE_IMAGE, "resources": small, "securityContext": security}],
        "terminationGracePeriodSeconds": 1,
    }
    if tolerations:
        pod["tolerations"] = tolerations
    if spec.get("affinity"):
        pod["affinity"] = dict(spec["affinity"])
    selector = {LABEL_NAME: PREPULL_APP, LABEL_POOL: meta["name"]}
    owner = {"apiVersion": API_VERSION, "kind": "NodePool", "name": meta["name"], "uid": meta["uid"]}
    return {
        "apiVersion": "apps/v1",
        "kind": "DaemonSet",
        "metadata": {
            "name": prepull_name(meta["name"]),
            "namespace": namespace,
            "labels": labels,
            "ownerReferences": [owner],  # deleted with the pool
        },
        "spec": {
            "selector": {"matchLabels": selector},
            # Pulling is all it does: a new image list may roll over every node at once.
            "updateStrategy": {"type": "RollingUpdate", "rollingUpdate": {"maxUnavailable": "100%"}},
            "template": {"metadata": {"labels": labels}, "spec": pod},
        },
    }


def operator_namespace(config: OperatorConfig) -> str:
    """Where the DaemonSets go: the configured namespace, else the operator's own (its service account's)."""
    if config.prepull_namespace:
        return config.prepull_namespace
    try:
        return Path(SERVICE_ACCOUNT_NAMESPACE_FILE).read_text().strip() or "default"
    except OSError:
        return "default"


class PrePull:
    """Keeps each NodePool's DaemonSet as `render_prepull` says; applies only what changed since the last time."""

    def __init__(self, kube: Any, config: OperatorConfig) -> None:
        self.kube = kube
        self.config = config
        self.namespace = operator_namespace(config)
        self._applied: dict[str, Manifest | None] = {}  # pool -> what was last applied (None: deleted)

    async def sync(self, pool: Mapping[str, Any], deleted: bool) -> None:
        name = pool["metadata"]["name"]
        wanted = None if deleted else render_prepull(pool, self.namespace, self.config)
        if name in self._applied and self._applied[name] == wanted:
            return
        if wanted is not None:
            await self.kube.apply(wanted)
            log.info("NodePool %s: its nodes pull %s ahead of its netapps", name, ", ".join(wanted_images(pool)))
        elif not deleted:  # a deleted pool's DaemonSet goes with it (its owner reference)
            await self.kube.delete("DaemonSet", self.namespace, prepull_name(name))
        self._applied[name] = wanted
        if deleted:
            self._applied.pop(name, None)
