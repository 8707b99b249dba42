"""netapp.models.providers.preload: with onnxruntime's CPU build nothing is loaded and the line says why; the
libraries it reports are the ones the process has mapped. The CUDA build's side runs in the GPU image's test
(tests/images, NETAPP_TEST_GPU_IMAGE=1), which checks cuBLAS, the CUDA runtime and cuDNN are loaded from the wheels."""

from __future__ import annotations

import onnxruntime

from netapp.models.providers import CUDA_PROVIDER, GpuLibs, loaded_libraries, preload


def test_the_cpu_build_loads_nothing_and_says_so():
    if CUDA_PROVIDER in onnxruntime.get_available_providers():
        assert preload().cuda_build
        return
    libs = preload()
    assert libs == GpuLibs(cuda_build=False) and preload() is libs  # once per process
    assert libs.describe() == "GPU libraries: none loaded (this onnxruntime is not its CUDA build)"


def test_the_report_names_what_the_process_has_mapped():
    assert any(name.startswith("libc.so") for name in loaded_libraries(("libc.so",)))
    assert loaded_libraries(("libno-such-library",)) == ()
    line = GpuLibs(True, ("libcudart.so.13", "libcudnn.so.9"), tensorrt=False).describe()
    assert line.startswith("GPU libraries: libcudart.so.13, libcudnn.so.9;") and "tensorrt" in line
