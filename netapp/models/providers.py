"""Which onnxruntime execution provider runs the model: `--device auto|cpu|cuda|tensorrt|openvino`. Pure: it
chooses from the providers onnxruntime reports, and says why."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

DEVICES = ("auto", "cpu", "cuda", "tensorrt", "openvino")
PROVIDERS = {
    "tensorrt": "TensorrtExecutionProvider",
    "cuda": "CUDAExecutionProvider",
    "openvino": "OpenVINOExecutionProvider",
    "cpu": "CPUExecutionProvider",
}
PREFERENCE = ("tensorrt", "cuda", "openvino", "cpu")  # what `auto` takes first, when onnxruntime offers it
DEFAULT_TRT_CACHE = Path("~/.cache/netapp/trt")


class DeviceUnavailable(ValueError):
    """The device asked for is not offered by this onnxruntime; the message says what is, and what to do."""


@dataclass(frozen=True)
class DeviceChoice:
    device: str
    providers: list[Any]  # onnxruntime's `providers` argument: names, or (name, options) pairs
    why: str


def provider_options(device: str, trt_cache: str | None, fp16: bool) -> dict[str, Any]:
    """Each provider's options: TensorRT keeps its engines (built once, minutes for a large model) in the cache."""
    if device == "tensorrt":
        cache = Path(trt_cache).expanduser() if trt_cache else DEFAULT_TRT_CACHE.expanduser()
        return {
            "trt_engine_cache_enable": True,
            "trt_engine_cache_path": str(cache),
            "trt_timing_cache_enable": True,
            "trt_timing_cache_path": str(cache),
            "trt_fp16_enable": fp16,
        }
    if device == "openvino":
        return {"precision": "FP16"} if fp16 else {}
    return {}


def choose_device(device: str, available: list[str], trt_cache: str | None = None, fp16: bool = False) -> DeviceChoice:
    """The providers for `device` from what onnxruntime offers; DeviceUnavailable (one line) when absent."""
    if device not in DEVICES:
        raise DeviceUnavailable(f"--device {device} is not one of {', '.join(DEVICES)}")
    offered = [d for d in PREFERENCE if PROVIDERS[d] in available]
    if device == "auto":
        chosen = offered[0] if offered else "cpu"
        why = f"auto: {chosen}, the best of those onnxruntime offers ({', '.join(offered) or 'none'})"
    elif device in offered:
        chosen, why = device, f"{device}, as --device asks"
    else:
        hint = {
            "cuda": "install onnxruntime-gpu (and NVIDIA's CUDA and cuDNN wheels) on a machine with an NVIDIA GPU",
            "tensorrt": "install onnxruntime-gpu and NVIDIA's TensorRT wheels on a machine with an NVIDIA GPU",
            "openvino": "install onnxruntime-openvino (pip install 'netapp-toolkit[openvino]')",
        }.get(device, "")
        raise DeviceUnavailable(
            f"--device {device}: this onnxruntime offers only {', '.join(offered) or 'no provider'}: "
            f"{hint}, or use --device auto"
        )
    # the chosen provider first, then CUDA under TensorRT and the CPU, which take the operators it cannot run
    chain = dict.fromkeys((chosen, "cuda" if chosen == "tensorrt" else chosen, "cpu"))
    providers: list[Any] = []
    for d in chain:
        if d in offered:
            options = provider_options(d, trt_cache, fp16)
            providers.append((PROVIDERS[d], options) if options else PROVIDERS[d])
    if fp16 and chosen in ("cuda", "cpu"):
        why += " (--fp16 applies to tensorrt and openvino only)"
    return DeviceChoice(chosen, providers, why)
