"""NetApp spec defaults and the checks a CRD schema cannot make everywhere (pure).

The CRD schema rejects most bad input at admission, but defaults and CEL rules are not applied by every API server
(nor by test emulators), so the operator applies the same defaults and checks again before it renders anything.
"""

from __future__ import annotations

import copy
import re
from collections.abc import Mapping
from typing import Any

from netapp_operator.constants import NETAPP_PORT

MODEL_DIR = "/models"
MODEL_FILE = "model.onnx"
_SHA256 = re.compile(r"^[0-9a-fA-F]{64}$")
# `netapp serve --processor`: a built-in name, or package.module:Class installed in the image
PROCESSOR = re.compile(r"^[A-Za-z_][A-Za-z0-9_.-]*(:[A-Za-z_][A-Za-z0-9_]*)?$")
_QUANTITY = re.compile(r"^[0-9]+(\.[0-9]+)?(m|k|Ki|M|Mi|G|Gi|T|Ti|P|Pi|E|Ei)?$")


def with_defaults(spec: Mapping[str, Any]) -> dict[str, Any]:
    """Return a copy of a NetApp spec with the CRD's defaults filled in."""
    out = copy.deepcopy(dict(spec))
    out.setdefault("port", NETAPP_PORT)
    out.setdefault("replicas", 1)
    out.setdefault("args", [])
    out.setdefault("env", [])
    placement = out.setdefault("placement", {})
    if "pool" not in placement:
        placement.setdefault("policy", "auto")
    placement.setdefault("requireGPU", False)
    resources = out.setdefault("resources", {})
    resources.setdefault("gpus", 0)
    if "autoscaling" in out:
        out["autoscaling"].setdefault("minReplicas", 1)
        out["autoscaling"].setdefault("targetCPUUtilizationPercentage", 70)
    model = out.get("model")
    if model and "url" in model:
        model.setdefault("timeoutSeconds", 300)
    return out


def custom_processor(spec: Mapping[str, Any]) -> str | None:
    """The `package.module:Class` a NetApp serves instead of a built-in processor; None for a built-in one."""
    processor = spec.get("processor")
    return processor if isinstance(processor, str) and ":" in processor else None


def requires_gpu(spec: Mapping[str, Any]) -> bool:
    """A netapp needs a GPU pool when it asks for one explicitly or requests GPUs."""
    return bool(spec.get("placement", {}).get("requireGPU")) or int(spec.get("resources", {}).get("gpus") or 0) > 0


def problems(spec: Mapping[str, Any]) -> list[str]:
    """Everything wrong with a (defaulted) NetApp spec, as human-readable sentences; empty when it is valid."""
    found: list[str] = []
    image = spec.get("image")
    if not isinstance(image, str) or not image.strip():
        found.append("spec.image is required")
    port = spec.get("port")
    if not isinstance(port, int) or isinstance(port, bool) or not 1 <= port <= 65535:
        found.append(f"spec.port must be an integer in 1..65535, got {port!r}")
    replicas = spec.get("replicas")
    if not isinstance(replicas, int) or isinstance(replicas, bool) or replicas < 0:
        found.append(f"spec.replicas must be an integer >= 0, got {replicas!r}")
    auto = spec.get("autoscaling")
    if auto is not None:
        lo, hi = auto.get("minReplicas"), auto.get("maxReplicas")
        if not isinstance(hi, int) or hi < 1:
            found.append("spec.autoscaling.maxReplicas must be an integer >= 1")
        elif not isinstance(lo, int) or lo < 1 or lo > hi:
            found.append("spec.autoscaling.minReplicas must be an integer in 1..maxReplicas")
        target = auto.get("targetCPUUtilizationPercentage")
        if not isinstance(target, int) or not 1 <= target <= 100:
            found.append("spec.autoscaling.targetCPUUtilizationPercentage must be in 1..100")
    processor = spec.get("processor")
    if processor is not None and not (isinstance(processor, str) and PROCESSOR.match(processor)):
        found.append(f"spec.processor must be a built-in name or package.module:Class, got {processor!r}")
    model = spec.get("model")
    if model is not None and custom_processor(spec):
        found.append("spec.model is for the built-in detector: a package.module:Class processor loads its own weights")
    if model is not None:
        if ("url" in model) == ("volume" in model):
            found.append("spec.model needs exactly one of url or volume")
        if "sha256" in model and not _SHA256.match(str(model["sha256"])):
            found.append("spec.model.sha256 must be 64 hexadecimal characters")
        volume = model.get("volume")
        if volume is not None and not (volume.get("claimName") and volume.get("path")):
            found.append("spec.model.volume needs claimName and path")
    resources = spec.get("resources", {})
    for key in ("cpu", "memory"):
        if key in resources and not _QUANTITY.match(str(resources[key])):
            found.append(f"spec.resources.{key} is not a Kubernetes quantity: {resources[key]!r}")
    gpus = resources.get("gpus", 0)
    if not isinstance(gpus, int) or gpus < 0:
        found.append("spec.resources.gpus must be an integer >= 0")
    placement = spec.get("placement", {})
    if placement.get("policy", "auto") not in ("edge", "cloud", "auto"):
        found.append(f"spec.placement.policy must be edge, cloud or auto, got {placement.get('policy')!r}")
    for item in spec.get("env", []):
        if not isinstance(item, Mapping) or not item.get("name"):
            found.append("every spec.env entry needs a name")
            break
    return found
