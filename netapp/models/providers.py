"""Which onnxruntime execution provider runs the model: `--device auto|cpu|cuda|tensorrt|openvino`. Pure: it
chooses from the providers onnxruntime reports, and says why.

One impure part, at the end: `preload()` loads the CUDA, cuDNN and TensorRT libraries that NVIDIA's PyPI wheels
install, before onnxruntime needs them. onnxruntime's CUDA build links `libcudart`, `libcublas`, `libcudnn` (and its
TensorRT provider `libnvinfer`) by name; the wheels put them in site-packages, where the dynamic loader does not
look. `onnxruntime.preload_dlls()` loads the CUDA and cuDNN ones from there; TensorRT's (`tensorrt_libs`) are loaded
the same way, globally, so that the providers find them already loaded. Without the CUDA build it does nothing.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import importlib.util
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from netapp.protocol import DEVICES

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


# --- the GPU libraries from NVIDIA's wheels (the impure part) ---------------------------------------------------

CUDA_PROVIDER = PROVIDERS["cuda"]
# TensorRT's libraries in load order (the parser and plugins need libnvinfer); any major version the wheel brings.
TENSORRT_LIBS = ("libnvinfer.so.*", "libnvinfer_plugin.so.*", "libnvonnxparser.so.*")
# What the report names: the libraries a GPU provider needs, as the process has them mapped.
_REPORTED = ("libcudart", "libcublas.", "libcublasLt", "libcudnn.", "libcufft", "libcurand", "libnvrtc", "libnvinfer.")


@dataclass(frozen=True)
class GpuLibs:
    """What `preload` found: whether onnxruntime is its CUDA build, and which NVIDIA libraries are now loaded."""

    cuda_build: bool
    loaded: tuple[str, ...] = ()
    tensorrt: bool = False

    def describe(self) -> str:
        """One line for the start-up log."""
        if not self.cuda_build:
            return "GPU libraries: none loaded (this onnxruntime is not its CUDA build)"
        trt = "with TensorRT" if self.tensorrt else "no TensorRT libraries (pip install 'netapp-toolkit[tensorrt]')"
        return f"GPU libraries: {', '.join(self.loaded) or 'none found'}; {trt}"


def loaded_libraries(names: tuple[str, ...] = _REPORTED) -> tuple[str, ...]:
    """The shared libraries this process has mapped whose file names start with one of `names` (from /proc)."""
    try:
        maps = Path("/proc/self/maps").read_text()
    except OSError:
        return ()
    files = {line.rsplit("/", 1)[-1] for line in maps.splitlines() if "/" in line}
    return tuple(sorted(f for f in files if f.startswith(names)))


def _tensorrt_dir() -> Path | None:
    spec = importlib.util.find_spec("tensorrt_libs")
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations)))


def _load_tensorrt() -> bool:
    """TensorRT's libraries from the `tensorrt_libs` wheel, global, so that the TensorRT provider finds them."""
    folder = _tensorrt_dir()
    if folder is None:
        return False
    for pattern in TENSORRT_LIBS:
        for path in sorted(folder.glob(pattern))[:1]:
            ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
    return bool(loaded_libraries(("libnvinfer.",)))


@functools.cache
def preload() -> GpuLibs:
    """Load the GPU libraries once per process (idempotent); returns what is loaded."""
    try:
        import onnxruntime as ort
    except ImportError:
        return GpuLibs(cuda_build=False)
    if CUDA_PROVIDER not in ort.get_available_providers():
        return GpuLibs(cuda_build=False)
    preload_dlls = getattr(ort, "preload_dlls", None)  # onnxruntime >= 1.21
    if preload_dlls is not None:
        with contextlib.redirect_stdout(sys.stderr):  # it prints what failed; stdout may be a protocol
            preload_dlls()
    tensorrt = _load_tensorrt()
    return GpuLibs(cuda_build=True, loaded=loaded_libraries(), tensorrt=tensorrt)
