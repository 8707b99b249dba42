#!/bin/sh
# Say which onnxruntime provider this container uses (CUDA with a GPU, else CPU), hand the choice to the server
# through NETAPP_ORT_PROVIDERS, then become the server.
set -eu
NETAPP_ORT_PROVIDERS="${NETAPP_ORT_PROVIDERS:-$(/opt/venv/bin/python /opt/netapp/ort_provider.py)}"
export NETAPP_ORT_PROVIDERS
echo "netapp: onnxruntime providers ${NETAPP_ORT_PROVIDERS}" >&2
exec /opt/venv/bin/netapp serve "$@"
