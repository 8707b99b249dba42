#!/bin/sh
# Say which onnxruntime provider this container will use and why (CUDA with a GPU, else the CPU and the reason),
# then become the server (which picks CUDA when onnxruntime offers it and logs the provider it got).
set -eu
/opt/venv/bin/python /opt/netapp/ort_provider.py >/dev/null
exec /opt/venv/bin/netapp serve "$@"
