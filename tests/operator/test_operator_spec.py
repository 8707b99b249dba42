"""Pure spec checks: the operator re-applies the CRD's defaults and rejects what a schema may not catch."""

from __future__ import annotations

import pytest
from netapp_operator.spec import Autoscaling, Placement, parse


def test_defaults_match_the_crd():
    spec = parse({"image": "i", "autoscaling": {"maxReplicas": 3}, "model": {"url": "https://x"}})
    assert spec.port == 5896 and spec.replicas == 1
    assert spec.placement == Placement(pool=None, policy="auto", require_gpu=False)
    assert spec.autoscaling == Autoscaling(max_replicas=3, min_replicas=1, target_cpu_percent=70)
    assert spec.model.timeout_seconds == 300
    assert spec.admission == "open"
    assert spec.priority.robots == "normal" and spec.priority.token_sha256 == {}
    assert spec.problems == ()


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
        ({"image": "i", "state": {"volume": {}}}, "spec.state needs volume.claimName"),
        ({"image": "i", "admission": "strict"}, "spec.admission must be one of open, measured"),
        ({"image": "i", "priority": {"robots": "vip"}}, "spec.priority.robots must be one of low, normal, high"),
        ({"image": "i", "priority": {"tokenSha256": {"vip": "0" * 64}}}, "spec.priority.tokenSha256 maps a class"),
        ({"image": "i", "priority": {"tokenSha256": {"high": "nothex"}}}, "spec.priority.tokenSha256 maps a class"),
        ({"image": "i", "standby": {"replicas": 0}}, "spec.standby.replicas must be an integer in 1..4"),
        ({"image": "i", "standby": {"policy": "random"}}, "spec.standby.policy must be nextBest"),
        ({"image": "i", "device": "tpu"}, "spec.device must be one of auto, cpu, cuda, tensorrt, openvino"),
        ({"image": "i", "fp16": "yes"}, "spec.fp16 must be true or false"),
        ({"image": "i", "device": "cuda", "engineCache": {}}, "spec.engineCache is TensorRT's"),
        ({"image": "i", "engineCache": {"sizeLimit": "big"}}, "spec.engineCache.sizeLimit is not a Kubernetes"),
        ({"image": "i", "engineCache": {"claimName": ""}}, "spec.engineCache.claimName must name"),
    ],
)
def test_problems(spec, text):
    found = parse(spec).problems
    assert any(text in p for p in found), found


def test_gpu_requirement():
    assert parse({"image": "i", "resources": {"gpus": 1}}).requires_gpu
    assert parse({"image": "i", "placement": {"requireGPU": True}}).requires_gpu
    assert not parse({"image": "i"}).requires_gpu


@pytest.mark.parametrize(
    ("sources", "text"),
    [
        ([{"name": "door"}], "needs a name and an rtsp:// url"),
        (["door=rtsp://cam/x"], "needs a name and an rtsp:// url"),
        ([{"name": "door", "url": "http://cam/x"}], "spec.sources: source door: give an rtsp://"),
        ([{"name": "door", "url": "rtsp://a/x"}, {"name": "door", "url": "rtsp://b/x"}], "door given twice"),
    ],
)
def test_cameras_netapp_serve_would_refuse_are_problems_of_the_spec(sources, text):
    problems = parse({"image": "i", "sources": sources}).problems
    assert len(problems) == 1 and text in problems[0]


def test_cameras_in_the_spec_are_the_netapps_source_flags():
    from netapp_operator.spec import source_args

    spec = parse({"image": "i", "sources": [{"name": "door", "url": "rtsp://10.0.0.5/s#transport=tcp"}]})
    assert spec.problems == ()
    assert source_args(spec.sources) == ["--source", "door=rtsp://10.0.0.5/s#transport=tcp"]
    # a GPU device needs a GPU: at least one is requested, more when resources.gpus asks
    for device in ("cuda", "tensorrt"):
        spec = parse({"image": "i", "device": device})
        assert spec.gpus == 1 and spec.requires_gpu
    assert parse({"image": "i", "device": "cuda", "resources": {"gpus": 2}}).gpus == 2
    for device in ("auto", "cpu", "openvino"):
        assert not parse({"image": "i", "device": device}).requires_gpu


def test_device_defaults_and_the_engine_cache():
    spec = parse({"image": "i"})
    assert spec.device == "auto" and spec.fp16 is False and spec.trt_cache is None and spec.problems == ()
    trt = parse({"image": "i", "device": "tensorrt"})
    assert trt.trt_cache.claim_name is None and trt.trt_cache.size_limit == "2Gi"  # an emptyDir when none is named
    kept = parse({"image": "i", "device": "tensorrt", "fp16": True, "engineCache": {"claimName": "engines"}})
    assert kept.trt_cache.claim_name == "engines" and kept.fp16 and kept.problems == ()
