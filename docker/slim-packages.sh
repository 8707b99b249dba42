#!/bin/sh
# Remove from a folder of installed packages (a venv's site-packages, a layer's folder) what no netapp process
# imports (measured in docs/images.md): test suites, type stubs, onnxruntime's model tooling and its C-API library
# (its Python module does not link it: `readelf -d` shows only the system libraries). numpy.f2py stays: scipy
# imports it. Then strip the debug sections of the extension modules that carry them (uvloop's 13.6 MB module is
# 1.9 MB without); where no binutils are, that step is left out. The image test runs a detection and a tracker on
# what is left.
set -eu
site="$1"
find "$site" -depth -type d \( -name tests -o -name test \) -exec rm -rf {} +
find "$site" -name '*.pyi' -delete
rm -rf "$site"/onnxruntime/transformers "$site"/onnxruntime/tools "$site"/onnxruntime/quantization \
    "$site"/onnxruntime/capi/libonnxruntime.so* "$site"/numpy/_pyinstaller
# NVIDIA's wheels (the GPU image): C headers and static libraries, for compilers, not for onnxruntime.
if [ -d "$site"/nvidia ]; then
    find "$site"/nvidia -depth -type d -name include -exec rm -rf {} +
    find "$site"/nvidia -name '*.a' -delete
fi
if command -v strip >/dev/null && command -v readelf >/dev/null; then
    find "$site" -name '*.so' -type f | while read -r lib; do
        if readelf -S "$lib" | grep -q '\.debug_info'; then strip --strip-debug "$lib"; fi
    done
fi
