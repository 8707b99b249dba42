"""Pick onnxruntime's execution provider for this container and say so at start-up.

CUDA when the CUDA build of onnxruntime is installed *and* the driver reports a GPU (the CUDA provider is listed
as available even on a machine without one), else the CPU. Prints the choice and the reason on stderr, and the
providers in onnxruntime's order on stdout.

    python ort_provider.py            # prints e.g. CUDAExecutionProvider,CPUExecutionProvider
"""

from __future__ import annotations

import ctypes
import sys


def cuda_devices() -> tuple[int, str]:
    """Number of GPUs the CUDA driver sees, and why none when 0 (no libcuda, init failure, no device)."""
    try:
        cuda = ctypes.CDLL("libcuda.so.1")
    except OSError:
        return 0, "no CUDA driver (libcuda.so.1) in this container"
    if cuda.cuInit(0) != 0:
        return 0, "the CUDA driver found no usable GPU (cuInit failed)"
    count = ctypes.c_int(0)
    if cuda.cuDeviceGetCount(ctypes.byref(count)) != 0:
        return 0, "cuDeviceGetCount failed"
    return count.value, f"{count.value} GPU(s)"


def choose() -> tuple[list[str], str]:
    try:
        import onnxruntime

        available = onnxruntime.get_available_providers()
        version = onnxruntime.__version__
    except ImportError:
        available, version = [], "missing"
    gpus, why = cuda_devices()
    if "CUDAExecutionProvider" in available and gpus > 0:
        return ["CUDAExecutionProvider", "CPUExecutionProvider"], f"onnxruntime {version}: CUDA provider ({why})"
    if "CUDAExecutionProvider" not in available:
        why = f"this onnxruntime build has no CUDA provider (available: {', '.join(available) or 'none'})"
    return ["CPUExecutionProvider"], f"onnxruntime {version}: CPU provider ({why})"


if __name__ == "__main__":
    providers, message = choose()
    print(message, file=sys.stderr, flush=True)
    print(",".join(providers))
