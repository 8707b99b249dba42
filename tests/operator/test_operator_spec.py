"""Pure spec checks: the operator re-applies the CRD's defaults and rejects what a schema may not catch."""

from __future__ import annotations

import pytest
from netapp_operator.spec import problems, requires_gpu, with_defaults


def test_defaults_match_the_crd():
    spec = with_defaults({"image": "i", "autoscaling": {"maxReplicas": 3}, "model": {"url": "https://x"}})
    assert spec["port"] == 5896 and spec["replicas"] == 1
    assert spec["placement"] == {"policy": "auto", "requireGPU": False}
    assert spec["autoscaling"] == {"maxReplicas": 3, "minReplicas": 1, "targetCPUUtilizationPercentage": 70}
    assert spec["model"]["timeoutSeconds"] == 300
    assert problems(spec) == []


@pytest.mark.parametrize(
    "spec, text",
    [
        ({}, "spec.image is required"),
        ({"image": " "}, "spec.image is required"),
        ({"image": "i", "replicas": -1}, "spec.replicas"),
        ({"image": "i", "replicas": "two"}, "spec.replicas"),
        ({"image": "i", "port": 70000}, "spec.port"),
        ({"image": "i", "autoscaling": {"minReplicas": 5, "maxReplicas": 2}}, "minReplicas"),
        ({"image": "i", "model": {"url": "https://x", "volume": {"claimName": "c", "path": "p"}}}, "exactly one"),
        ({"image": "i", "model": {"url": "https://x", "sha256": "xyz"}}, "sha256"),
        ({"image": "i", "resources": {"memory": "lots"}}, "quantity"),
        ({"image": "i", "env": [{"value": "x"}]}, "env"),
        ({"image": "i", "processor": "rm -rf /"}, "spec.processor"),
        ({"image": "i", "processor": "pkg.mod:Cls", "model": {"url": "https://x"}}, "loads its own weights"),
    ],
)
def test_problems(spec, text):
    found = problems(with_defaults(spec))
    assert any(text in p for p in found), found


def test_gpu_requirement():
    assert requires_gpu(with_defaults({"image": "i", "resources": {"gpus": 1}}))
    assert requires_gpu(with_defaults({"image": "i", "placement": {"requireGPU": True}}))
    assert not requires_gpu(with_defaults({"image": "i"}))
