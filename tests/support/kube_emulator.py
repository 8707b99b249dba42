"""A Kubernetes API emulator for tests and benchmarks: kmock plus the behaviour the operator relies on.

kmock (by kopf's author) serves in-memory objects with real watch streams, but it assigns no uid,
resourceVersion, creationTimestamp or generation, allocates no NodePorts, collects no garbage, lets a `/status`
patch change the whole object, and only knows resources declared up front. `Emulator` fills those gaps;
`declare` declares the built-in kinds the operator uses and the project's CRDs (read from their YAML files, the
single definition of the schemas). Test scaffolding (it needs the `test` extra), used by the tests and
bench/operator_bench.py; it ships in no wheel.
"""

from __future__ import annotations

import copy
import datetime
import itertools
import pathlib
import uuid
from collections.abc import Mapping
from typing import Any

import kmock
import yaml
from kmock._internal import aiobus

from tests.support.kmock_dispatch import FastDispatch
from tests.support.kmock_rendering import lighten_rendering
from tests.support.paths import ROOT

# tests/support/ -> the repository root. The chart is the single source of the CRDs (manifests/ is rendered from it).
CRD_DIR = ROOT / "charts" / "netapp-toolkit" / "crds"

BUILTIN = {
    "v1/nodes": dict(kind="Node", namespaced=False),
    "v1/namespaces": dict(kind="Namespace", namespaced=False),
    "v1/services": dict(kind="Service", namespaced=True, subresources={"status"}),
    "discovery.k8s.io/v1/endpointslices": dict(kind="EndpointSlice", namespaced=True),  # the waker's (waker.py)
    "v1/events": dict(kind="Event", namespaced=True),
    "v1/pods": dict(kind="Pod", namespaced=True, subresources={"status"}),  # a rollout's pod (tests/operator)
    "v1/secrets": dict(kind="Secret", namespaced=True),
    "networking.k8s.io/v1/networkpolicies": dict(kind="NetworkPolicy", namespaced=True),
    "apps/v1/deployments": dict(kind="Deployment", namespaced=True, subresources={"status", "scale"}),
    "autoscaling/v2/horizontalpodautoscalers": dict(
        kind="HorizontalPodAutoscaler", namespaced=True, subresources={"status"}
    ),
    "keda.sh/v1alpha1/scaledobjects": dict(kind="ScaledObject", namespaced=True, subresources={"status"}),
    "coordination.k8s.io/v1/leases": dict(kind="Lease", namespaced=True),  # a netapp's cameras
    # what the operator gives a NetApp's replicas for those Leases (netapp_operator/cameras.py)
    "v1/serviceaccounts": dict(kind="ServiceAccount", namespaced=True),
    "rbac.authorization.k8s.io/v1/roles": dict(kind="Role", namespaced=True),
    "rbac.authorization.k8s.io/v1/rolebindings": dict(kind="RoleBinding", namespaced=True),
}
VERBS = {"create", "get", "list", "watch", "patch", "delete"}
WATCH_BUFFER = 256  # watch events kept after every watch has read them (_WatchBus)


def load_crds(directory: pathlib.Path = CRD_DIR) -> list[dict[str, Any]]:
    """The project's CustomResourceDefinitions, as parsed YAML."""
    crds = []
    for path in sorted(directory.glob("*.yaml")):
        for doc in yaml.safe_load_all(path.read_text()):
            if doc and doc.get("kind") == "CustomResourceDefinition":
                crds.append(doc)
    if not crds:
        raise FileNotFoundError(f"no CustomResourceDefinition found under {directory}")
    return crds


def declare(emulator: kmock.KubernetesEmulator, crds: list[dict[str, Any]] | None = None) -> None:
    """Declare the built-in resources and the CRDs, so that kopf's discovery finds them."""
    for key, info in BUILTIN.items():
        emulator.resources[key] = kmock.ResourceInfo(verbs=VERBS, **info)
    for crd in crds if crds is not None else load_crds():
        spec = crd["spec"]
        names = spec["names"]
        for version in spec["versions"]:
            emulator.resources[f"{spec['group']}/{version['name']}/{names['plural']}"] = kmock.ResourceInfo(
                kind=names["kind"],
                singular=names.get("singular"),
                namespaced=spec["scope"] == "Namespaced",
                shortnames=set(names.get("shortNames", [])),
                subresources=set(version.get("subresources", {})),
                verbs=VERBS,
            )


class _WatchBus(aiobus.Bus):
    """kmock's bus of a resource's watch events, freeing the events every watch has read once they are a few
    hundred, not after every event: kmock's bus looks at every watch's position (a weak dictionary) on every event
    put and read, 9 % of the emulator's CPU in a burst of 4,000 NetApps (py-spy, bench/operator_bench.py)."""

    async def _flush(self, forced: bool = False) -> None:
        if forced or len(self._buffer) >= WATCH_BUFFER:
            await super()._flush(forced)


def _merge(base: Any, patch: Any) -> Any:
    if not isinstance(base, Mapping) or not isinstance(patch, Mapping):
        return copy.deepcopy(patch)
    out = dict(base)
    for key, value in patch.items():
        if value is None:
            out.pop(key, None)
        else:
            out[key] = _merge(base.get(key), value)
    return out


def _equality_selector(selector: str) -> dict[str, str]:
    """`a=b,c==d` as {a: b, c: d}: the only label selectors the operator sends (sets and negations raise)."""
    wanted = {}
    for term in filter(None, (t.strip() for t in selector.split(","))):
        key, sep, value = term.partition("==") if "==" in term else term.partition("=")
        if not sep or "!" in key:
            raise ValueError(f"the emulator supports only equality label selectors, not {term!r}")
        wanted[key.strip()] = value.strip()
    return wanted


class Emulator(kmock.KubernetesEmulator, FastDispatch):
    """kmock's KubernetesEmulator with server-assigned metadata, NodePorts, status isolation and garbage
    collection of owned objects, and constant-time request handling.

    kmock matches every request against all requests it has ever served and finds objects by scanning all of
    them, so a request costs O(history) and a benchmark of hundreds of NetApps would measure kmock. Here served
    requests move to `log`, single objects are looked up by key, and `FastDispatch` picks the reaction for a
    request without scanning the requests still in flight; `lighten_rendering` spares kmock an
    `inspect.signature` of its callback per request and encodes its JSON with orjson."""

    def __attrs_post_init__(self) -> None:
        super().__attrs_post_init__()
        lighten_rendering()
        self._buses.default_factory = _WatchBus
        self._versions = itertools.count(1)
        self._node_ports = itertools.count(30000)
        self.log: list[Any] = []  # every request served, for assertions (e.g. which verbs the operator used)

    def lookup(self, resource: Any, namespace: str | None, name: str | None) -> Any:
        """The live object by key, in constant time (kmock's `objects[...]` scans them all), or None."""
        obj = self.objects._objects.get((resource, namespace, name))
        return None if obj is None or obj.deleted else obj

    def _existing(self, request: Any) -> dict[str, Any] | None:
        obj = self.lookup(request.resource, request.namespace, request.name)
        return None if obj is None else obj.raw

    async def _serve_fetch(self, request: Any) -> Any:
        obj = self.lookup(request.resource, request.namespace, request.name)
        if obj is None:
            raise kmock.KubernetesObjectNotFoundError()
        return obj.raw

    async def _serve_list(self, request: Any) -> Any:
        # A real API server filters by label before it encodes (kmock ignores selectors): without it, listing a
        # NetApp's children encodes every child in the namespace, O(NetApps) per list.
        payload = await super()._serve_list(request)
        wanted = _equality_selector(request.params.get("labelSelector", ""))
        if wanted:
            payload["items"] = [
                item
                for item in payload["items"]
                if all(((item.get("metadata") or {}).get("labels") or {}).get(k) == v for k, v in wanted.items())
            ]
        return payload

    async def _serve_create(self, request: Any) -> Any:
        meta = request.data.get("metadata", {})
        obj = self.objects._objects[(request.resource, request.namespace or meta.get("namespace"), meta.get("name"))]
        return obj.raw

    async def _serve_update(self, request: Any) -> Any:
        return self.objects._objects[(request.resource, request.namespace, request.name)].last.raw

    async def _serve_delete(self, request: Any) -> Any:
        return self.objects._objects[(request.resource, request.namespace, request.name)].last.raw

    def _prepare(self, request: Any) -> None:
        data = request.data
        if not isinstance(data, dict):
            return
        now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
        meta = data.setdefault("metadata", {})
        if request.action == kmock.action.CREATE:
            meta["uid"] = str(uuid.uuid4())
            meta["creationTimestamp"] = now
            meta["generation"] = 1
            meta["resourceVersion"] = str(next(self._versions))
            if request.namespace and not meta.get("namespace"):
                meta["namespace"] = request.namespace
            if data.get("kind") == "Service" and data.get("spec", {}).get("type") in ("NodePort", "LoadBalancer"):
                for port in data["spec"].get("ports", []):
                    port.setdefault("nodePort", next(self._node_ports))
        elif request.action == kmock.action.UPDATE:
            existing = self._existing(request)
            for key in ("uid", "creationTimestamp", "generation"):  # owned by the server
                meta.pop(key, None)
            if request.subresource == "status":
                # A real API server ignores everything but status on /status; kmock would merge it all.
                for key in list(data):
                    if key not in ("status", "metadata"):
                        del data[key]
                meta.clear()
            elif existing is not None and "spec" in data and "status" in data:
                del data["status"]  # and status on the main resource (the CRDs have a status subresource)
            ports = (data.get("spec") or {}).get("ports")
            if existing is not None and existing.get("kind") == "Service" and isinstance(ports, list):
                # Like the real API server, keep an allocated NodePort that an update does not mention
                # (kmock replaces lists wholesale).
                allocated = {
                    p.get("name") or p.get("port"): p.get("nodePort") for p in existing.get("spec", {}).get("ports", [])
                }
                kind = data["spec"].get("type", existing.get("spec", {}).get("type"))
                for port in ports:
                    if kind in ("NodePort", "LoadBalancer") and not port.get("nodePort"):
                        port["nodePort"] = allocated.get(port.get("name") or port.get("port")) or next(self._node_ports)
            if existing is not None and "spec" in data and request.subresource is None:
                merged = _merge(existing.get("spec"), data["spec"])
                if merged != existing.get("spec"):
                    meta["generation"] = int(existing.get("metadata", {}).get("generation", 1)) + 1
            meta["resourceVersion"] = str(next(self._versions))

    async def _handle(self, request: Any) -> Any:
        uid = None
        if self._applies_to_missing(request):
            # A real API server creates the object a server-side apply names when it does not exist yet; kmock
            # answers 404. Serve it as the create it is, so the operator's requests are the ones a cluster sees.
            object.__setattr__(request, "action", kmock.action.CREATE)
        if request.resource is not None and request.action in (kmock.action.CREATE, kmock.action.UPDATE):
            self._prepare(request)
        elif request.resource is not None and request.action == kmock.action.DELETE and request.name:
            existing = self._existing(request)
            uid = (existing or {}).get("metadata", {}).get("uid")
        try:
            response = await super()._handle(request)
        finally:
            self._forget(request)
        if uid is not None and self._existing(request) is None:
            await self._collect_garbage({uid})
        return response

    def _applies_to_missing(self, request: Any) -> bool:
        # The headers last: scanning them for every request was 4 % of the emulator's CPU in a burst.
        return (
            request.resource is not None
            and request.action == kmock.action.UPDATE
            and request.subresource is None
            and isinstance(request.data, dict)
            and self._existing(request) is None
            and next((v for k, v in request.headers.items() if k.lower() == "content-type"), "").startswith(
                "application/apply-patch"
            )
        )

    def _forget(self, request: Any) -> None:
        for i in range(len(self._requests) - 1, -1, -1):
            if self._requests[i] is request:
                del self._requests[i]
                break
        self.log.append(request)

    async def _collect_garbage(self, owners: set[str]) -> None:
        """Delete what the deleted objects owned, like the garbage collector does (in the background)."""
        while owners:
            collected: set[str] = set()
            for (resource, _ns, _name), obj in list(self.objects.items()):
                if obj.deleted:
                    continue
                raw = obj.raw
                refs = raw.get("metadata", {}).get("ownerReferences") or []
                if any(ref.get("uid") in owners for ref in refs):
                    obj.delete()
                    await self._buses[resource].put({"type": "DELETED", "object": raw})
                    collected.add(raw["metadata"].get("uid"))
            owners = {uid for uid in collected if uid}


def kubeconfig(server: str) -> str:
    """A kubeconfig (YAML) for an emulator's URL."""
    return yaml.safe_dump(
        {
            "apiVersion": "v1",
            "kind": "Config",
            "clusters": [{"name": "kmock", "cluster": {"server": server}}],
            "users": [{"name": "kmock", "user": {"token": "kmock"}}],
            "contexts": [{"name": "kmock", "context": {"cluster": "kmock", "user": "kmock"}}],
            "current-context": "kmock",
        }
    )
