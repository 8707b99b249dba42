"""Load the CUDA, cuDNN and TensorRT libraries that NVIDIA's PyPI wheels install, before onnxruntime needs them.

onnxruntime's CUDA build links `libcudart`, `libcublas`, `libcudnn` (and its TensorRT provider `libnvinfer`) by
name; NVIDIA's wheels put them in site-packages, where the dynamic loader does not look. `onnxruntime.preload_dlls()`
loads the CUDA and cuDNN ones from there; TensorRT's (`tensorrt_libs`) are loaded here the same way, globally, so
that the providers find them already loaded. Call `preload()` once before the first InferenceSession; without the
CUDA build of onnxruntime it does nothing. The GPU image's entrypoint calls it (docker/gpu_entrypoint.py).
"""

from __future__ import annotations

import contextlib
import ctypes
import dataclasses
import functools
import importlib.util
import sys
from pathlib import Path

CUDA_PROVIDER = "CUDAExecutionProvider"
# TensorRT's libraries in load order (the parser and plugins need libnvinfer); any major version the wheel brings.
TENSORRT_LIBS = ("libnvinfer.so.*", "libnvinfer_plugin.so.*", "libnvonnxparser.so.*")
# What the report names: the libraries a GPU provider needs, as the process has them mapped.
_REPORTED = ("libcudart", "libcublas.", "libcublasLt", "libcudnn.", "libcufft", "libcurand", "libnvrtc", "libnvinfer.")


@dataclasses.dataclass(frozen=True)
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
