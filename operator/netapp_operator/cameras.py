"""What a NetApp's replicas need to share its cameras (`spec.sources`, docs/cameras.md#several-replicas): each pulls
only the cameras whose Lease it holds (`netapp serve --camera-leases NAMESPACE`), so the pods get that flag, their
NetApp's name (the Leases' prefix), a ServiceAccount of their own, and a Role allowing exactly what
`netapp/server/sources/leases.py` does: create a Lease, and get and patch the NetApp's own camera Leases by name.

Rendered for every NetApp with cameras, whatever its replica count: a rolling update runs two pods at once, and an
autoscaler may add more. Pure functions; the objects are owned by the NetApp, so they go with it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from netapp.protocol import NETAPP_NAME_ENV
from netapp.server.sources.leases import lease_name
from netapp_operator.constants import LABEL_INSTANCE, LABEL_MANAGED_BY, LABEL_NAME, NETAPP_APP_NAME, OPERATOR_MANAGER

CAMERA_KINDS = ("ServiceAccount", "Role", "RoleBinding")
RBAC_API = "rbac.authorization.k8s.io"


def camera_names(sources: tuple[Any, ...]) -> list[str]:
    """The cameras' names of a valid `spec.sources`."""
    return [str(s["name"]) for s in sources if isinstance(s, Mapping) and s.get("name")]


def camera_access_name(netapp: str) -> str:
    """The ServiceAccount, Role and RoleBinding of a NetApp's cameras (one set per NetApp, whichever its pool)."""
    return f"{netapp}-cameras"[:253]


def camera_pod(netapp: Mapping[str, Any], sources: tuple[Any, ...]) -> tuple[list[str], list[dict[str, Any]]]:
    """(server args, env) of a netapp pod with cameras: its Leases in its own namespace, named after its NetApp; the
    pod's name from the downward API (its identity when it has no --advertise-url)."""
    if not camera_names(sources):
        return [], []
    meta = netapp["metadata"]
    env = [
        {"name": NETAPP_NAME_ENV, "value": meta["name"]},
        {"name": "POD_NAME", "valueFrom": {"fieldRef": {"fieldPath": "metadata.name"}}},
    ]
    return ["--camera-leases", meta["namespace"]], env


def render_camera_access(netapp: Mapping[str, Any], sources: tuple[Any, ...], owner: dict[str, Any]) -> list[dict]:
    """The ServiceAccount, Role and RoleBinding of a NetApp with cameras (none without). Least privilege: `create`
    cannot be limited to names in RBAC, so it is alone; `get` and `patch` name this NetApp's Leases only."""
    cameras = camera_names(sources)
    if not cameras:
        return []
    meta = netapp["metadata"]
    name, namespace = camera_access_name(meta["name"]), meta["namespace"]
    metadata = {
        "name": name,
        "namespace": namespace,
        "labels": {LABEL_NAME: NETAPP_APP_NAME, LABEL_INSTANCE: meta["name"], LABEL_MANAGED_BY: OPERATOR_MANAGER},
        "ownerReferences": [owner],
    }
    leases = sorted({lease_name(meta["name"], camera) for camera in cameras})
    rules = [
        {"apiGroups": ["coordination.k8s.io"], "resources": ["leases"], "verbs": ["create"]},
        {
            "apiGroups": ["coordination.k8s.io"],
            "resources": ["leases"],
            "resourceNames": leases,
            "verbs": ["get", "patch"],
        },
    ]
    return [
        {
            "apiVersion": "v1",
            "kind": "ServiceAccount",
            "metadata": dict(metadata),
            "automountServiceAccountToken": False,
        },
        {"apiVersion": f"{RBAC_API}/v1", "kind": "Role", "metadata": dict(metadata), "rules": rules},
        {
            "apiVersion": f"{RBAC_API}/v1",
            "kind": "RoleBinding",
            "metadata": dict(metadata),
            "roleRef": {"apiGroup": RBAC_API, "kind": "Role", "name": name},
            "subjects": [{"kind": "ServiceAccount", "name": name, "namespace": namespace}],
        },
    ]
