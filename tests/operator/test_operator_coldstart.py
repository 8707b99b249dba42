"""Starting a netapp pod without the network in the way: the node's model cache (rendered, and its init script run
against a stub download), the startup probe, and the NodePools' image pre-pull (rendered, validated against the
Kubernetes schemas and the CRD, kept by `PrePull`)."""

from __future__ import annotations

import asyncio
import hashlib
import os
import subprocess
from pathlib import Path
from typing import Any

import jsonschema
import pytest
from netapp_operator.config import OperatorConfig
from netapp_operator.constants import NETAPP_IMAGE
from netapp_operator.model_fetch import CACHE_MOUNT
from netapp_operator.prepull import PrePull, prepull_name, render_prepull

from tests.operator.test_operator_render import kinds, netapp, pool, render
from tests.operator.test_operator_schemas import _schema
from tests.support.kubernetes_versions import KUBERNETES_VERSIONS

SHA = "ab" * 32
MODEL = {"url": "https://models.example.com/y.onnx", "sha256": SHA, "timeoutSeconds": 60}


def pod_of(na: dict, config: OperatorConfig | None = None) -> dict:
    return kinds(render(na, pool(), config))["Deployment"]["spec"]["template"]["spec"]


def test_a_model_with_a_sha256_is_fetched_through_the_nodes_cache() -> None:
    pod = pod_of(netapp(model=MODEL), OperatorConfig(model_cache_dir="/var/cache/m"))
    [init] = pod["initContainers"]
    env = {e["name"]: e["value"] for e in init["env"]}
    assert env["MODEL_CACHE"] == CACHE_MOUNT and env["MODEL_SHA256"] == SHA
    assert {"name": "model-cache", "mountPath": CACHE_MOUNT} in init["volumeMounts"]
    assert {"name": "model-cache", "hostPath": {"path": "/var/cache/m", "type": "DirectoryOrCreate"}} in pod["volumes"]
    # The netapp sees only its own checked copy, read-only; never the node's cache.
    [netapp_container] = pod["containers"]
    assert [m["name"] for m in netapp_container["volumeMounts"] if m["name"].startswith("model")] == ["model"]
    # The default model has a sha256 too: cached.
    assert "model-cache" in {v["name"] for v in pod_of(netapp())["volumes"]}


@pytest.mark.parametrize(
    "model, config",
    [
        ({"url": "https://models.example.com/y.onnx"}, OperatorConfig()),  # nothing to verify it by
        (MODEL, OperatorConfig(model_cache_dir="")),  # the operator keeps no cache
    ],
)
def test_no_cache_without_a_sha256_or_a_cache_dir(model: dict, config: OperatorConfig) -> None:
    pod = pod_of(netapp(model=model), config)
    [init] = pod["initContainers"]
    assert "MODEL_CACHE" not in {e["name"] for e in init["env"]}
    assert "model-cache" not in {v["name"] for v in pod["volumes"]}


def test_the_startup_probe_asks_readyz_every_second_so_the_pod_is_ready_the_moment_it_can_serve() -> None:
    [c] = pod_of(netapp())["containers"]
    probe = c["startupProbe"]
    assert probe["httpGet"] == {"path": "/readyz", "port": "http"} and probe["periodSeconds"] == 1
    assert probe["periodSeconds"] * probe["failureThreshold"] >= 180  # a cold node's model load, TensorRT's too


# -- the init script itself, against a stub curl ---------------------------------------------------------------------


def fetch(tmp_path: Path, served: bytes | None, sha256: str, cache: Path) -> subprocess.CompletedProcess:
    """Run the rendered init script with `curl` serving `served` (None: the download fails)."""
    [init] = pod_of(netapp(model={**MODEL, "sha256": sha256}))["initContainers"]
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir(exist_ok=True)
    stub = bin_dir / "curl"
    if served is None:
        stub.write_text("#!/bin/sh\nexit 22\n")
    else:
        (tmp_path / "served").write_bytes(served)
        # curl ... --output FILE URL: copy the served bytes to FILE
        stub.write_text(
            '#!/bin/sh\nwhile [ $# -gt 0 ]; do [ "$1" = --output ] && out="$2"; shift; done\n'
            f'echo fetched >> "{tmp_path}/downloads"; cp "{tmp_path}/served" "$out"\n'
        )
    stub.chmod(0o755)
    models = tmp_path / "models"
    models.mkdir(exist_ok=True)
    (models / "model.onnx").unlink(missing_ok=True)
    env = {e["name"]: e["value"] for e in init["env"]}
    env.update(MODEL_PATH=str(models / "model.onnx"), MODEL_CACHE=str(cache), HOSTNAME="pod-1")
    env["PATH"] = f"{bin_dir}:{os.environ['PATH']}"
    return subprocess.run(init["command"], env=env, capture_output=True, text=True)


def downloads(tmp_path: Path) -> int:
    log = tmp_path / "downloads"
    return len(log.read_text().split()) if log.exists() else 0


def test_the_cache_is_verified_never_trusted_by_name(tmp_path: Path) -> None:
    model = b"onnx weights"
    sha = hashlib.sha256(model).hexdigest()
    cache = tmp_path / "cache"
    cache.mkdir()
    served = tmp_path / "models" / "model.onnx"
    # First pod on the node: downloaded, checked, kept in the cache under its sha256.
    first = fetch(tmp_path, model, sha, cache)
    assert first.returncode == 0, first.stderr
    assert served.read_bytes() == model and (cache / sha).read_bytes() == model and downloads(tmp_path) == 1
    assert [p.name for p in cache.iterdir()] == [sha]  # no temporary file left
    # The next pod, of any NetApp: from the cache, even with the network down.
    hit = fetch(tmp_path, None, sha, cache)
    assert hit.returncode == 0 and "from the node's cache" in hit.stdout and served.read_bytes() == model
    assert downloads(tmp_path) == 1
    # A forged (or partial) entry under the right name: not served; downloaded again and the entry replaced.
    (cache / sha).write_bytes(b"forged")
    again = fetch(tmp_path, model, sha, cache)
    assert again.returncode == 0 and served.read_bytes() == model and (cache / sha).read_bytes() == model
    assert downloads(tmp_path) == 2
    # A download that does not match: the pod fails, nothing is served or cached.
    other = hashlib.sha256(b"other").hexdigest()
    bad = fetch(tmp_path, model, other, cache)
    assert bad.returncode != 0 and not served.exists() and not (cache / other).exists()


def test_a_cache_the_pod_cannot_write_still_serves_the_checked_download(tmp_path: Path) -> None:
    model = b"onnx weights"
    sha = hashlib.sha256(model).hexdigest()
    missing = tmp_path / "no-such-dir"  # stands for a directory the netapp's uid may not write
    result = fetch(tmp_path, model, sha, missing)
    assert result.returncode == 0 and "not writable" in result.stdout
    assert (tmp_path / "models" / "model.onnx").read_bytes() == model


# -- the image pre-pull ----------------------------------------------------------------------------------------------


def nodepool(name: str = "edge", **spec: Any) -> dict:
    spec.setdefault("type", "edge")
    spec.setdefault("nodeSelector", {"netapp.dev/pool": name})
    meta = {"name": name, "uid": "0b3f6d2e-0000-4000-8000-00000000000a"}
    return {"apiVersion": "netapp.dev/v1alpha1", "kind": "NodePool", "metadata": meta, "spec": spec}


def test_a_pool_that_asks_gets_a_daemonset_holding_the_images_on_its_nodes() -> None:
    assert render_prepull(nodepool(), "netapp-system", OperatorConfig()) is None
    gpu = {"gpu": True, "tolerations": [{"key": "edge", "operator": "Exists", "effect": "NoSchedule"}]}
    ds = render_prepull(nodepool(prePull={}, **gpu), "netapp-system", OperatorConfig())
    assert ds is not None and ds["metadata"]["name"] == "netapp-prepull-edge"
    assert ds["metadata"]["namespace"] == "netapp-system"
    assert ds["metadata"]["ownerReferences"][0]["kind"] == "NodePool"  # goes with its pool
    pod = ds["spec"]["template"]["spec"]
    assert [c["image"] for c in pod["initContainers"]] == [NETAPP_IMAGE]  # the netapp image by default
    assert pod["nodeSelector"] == {"netapp.dev/pool": "edge"}
    assert {t["key"] for t in pod["tolerations"]} == {"edge", "nvidia.com/gpu"}
    images = render_prepull(nodepool(prePull={"images": ["a:1", "b:2", "a:1"]}), "ns", OperatorConfig())
    assert images is not None
    assert [c["image"] for c in images["spec"]["template"]["spec"]["initContainers"]] == ["a:1", "b:2"]
    assert len(prepull_name("p" * 80)) <= 63 and prepull_name("p" * 80) != prepull_name("p" * 79)


def test_the_rendered_daemonset_and_the_cached_deployment_are_valid_kubernetes() -> None:
    kubernetes_validate = pytest.importorskip("kubernetes_validate")
    ds = render_prepull(nodepool(prePull={"images": ["a:1"]}, gpu=True), "ns", OperatorConfig())
    deployment = kinds(render(netapp(model=MODEL), pool()))["Deployment"]
    for version in KUBERNETES_VERSIONS:
        kubernetes_validate.validate(ds, version, strict=True)
        kubernetes_validate.validate(deployment, version, strict=True)


def test_the_nodepool_crd_takes_prepull_and_bounds_it() -> None:
    jsonschema.validate(nodepool(prePull={}), _schema("NodePool"))
    jsonschema.validate(nodepool(prePull={"images": ["a:1"]}), _schema("NodePool"))
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(nodepool(prePull={"images": [""]}), _schema("NodePool"))
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(nodepool(prePull={"images": [f"i:{n}" for n in range(9)]}), _schema("NodePool"))


class FakeKube:
    def __init__(self) -> None:
        self.calls: list[tuple[str, str]] = []

    async def apply(self, manifest: dict) -> dict:
        self.calls.append(("apply", manifest["metadata"]["name"]))
        return manifest

    async def delete(self, kind: str, namespace: str | None, name: str) -> bool:
        self.calls.append(("delete", name))
        return True


def test_prepull_applies_what_changed_and_deletes_what_a_pool_no_longer_asks_for() -> None:
    kube = FakeKube()
    keeper = PrePull(kube, OperatorConfig(prepull_namespace="ns"))

    async def events() -> None:
        await keeper.sync(nodepool(prePull={}), deleted=False)
        await keeper.sync(nodepool(prePull={}), deleted=False)  # a status update: nothing to apply
        await keeper.sync(nodepool(prePull={"images": ["a:1"]}), deleted=False)
        await keeper.sync(nodepool(), deleted=False)  # no longer asks
        await keeper.sync(nodepool(), deleted=False)
        await keeper.sync(nodepool(prePull={}), deleted=True)  # the owner reference deletes it

    asyncio.run(events())
    name = "netapp-prepull-edge"
    assert kube.calls == [("apply", name), ("apply", name), ("delete", name)]


def test_a_tls_netapp_leaves_the_next_netapps_probes_plain() -> None:
    [tls] = pod_of(netapp(tls={"secretName": "netapp-tls"}))["containers"]
    assert tls["startupProbe"]["httpGet"]["scheme"] == "HTTPS"
    [plain] = pod_of(netapp())["containers"]
    assert "scheme" not in plain["startupProbe"]["httpGet"] and "scheme" not in plain["livenessProbe"]["httpGet"]
