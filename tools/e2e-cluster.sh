#!/usr/bin/env bash
# End-to-end on a real cluster: install the chart, apply a NetApp, wait for Ready, stream a frame to its URL,
# delete it. Runs only with KUBECONFIG set and NETAPP_E2E_CLUSTER=1 (it changes the cluster); skips otherwise.
#
#   KUBECONFIG=~/.kube/config NETAPP_E2E_CLUSTER=1 make e2e-cluster
#
# Knobs: NETAPP_E2E_POOL_SELECTOR (node label key=value of the test pool, default kubernetes.io/os=linux),
# NETAPP_E2E_NETAPP_IMAGE, NETAPP_E2E_CONTROL_PLANE_TAG (images, e.g. after `kind load docker-image`),
# NETAPP_E2E_FRAME (image to stream; default ../shared/media's first .jpg/.png), NETAPP_E2E_KEEP=1 (no uninstall).
set -euo pipefail
cd "$(dirname "$0")/.."
if [[ -z "${KUBECONFIG:-}" || "${NETAPP_E2E_CLUSTER:-}" != "1" ]]; then
    echo "SKIP: real-cluster end-to-end needs KUBECONFIG and NETAPP_E2E_CLUSTER=1"
    exit 0
fi
PY="${PYTHON:-python3}"
"$PY" tools/fetch_tools.py helm kubectl >/dev/null
export PATH="$PWD/.tools/bin:$PATH"

SELECTOR="${NETAPP_E2E_POOL_SELECTOR:-kubernetes.io/os=linux}"
IMAGE="${NETAPP_E2E_NETAPP_IMAGE:-ghcr.io/netapp-toolkit/netapp:0.1.0}"
TAG="${NETAPP_E2E_CONTROL_PLANE_TAG:-0.1.0}"
APP_NS="netapp-e2e-$RANDOM"
FRAME="${NETAPP_E2E_FRAME:-$(ls ../shared/media/*.jpg ../shared/media/*.png 2>/dev/null | head -n1 || true)}"

cleanup() {
    kubectl delete namespace "$APP_NS" --ignore-not-found --wait=false >/dev/null 2>&1 || true
    if [[ "${NETAPP_E2E_KEEP:-}" != "1" ]]; then
        helm uninstall netapp-toolkit -n netapp-system >/dev/null 2>&1 || true
    fi
}
trap cleanup EXIT

echo "== install the chart (one pool over nodes with ${SELECTOR})"
kubectl create namespace "$APP_NS"  # the middleware's Role lives there, so it comes first
helm upgrade --install netapp-toolkit charts/netapp-toolkit -n netapp-system --create-namespace \
    --set image.tag="$TAG" --set middleware.netappNamespace="$APP_NS" \
    --set-json "nodePools=[{\"name\":\"e2e\",\"type\":\"edge\",\"nodeSelector\":{\"${SELECTOR%%=*}\":\"${SELECTOR#*=}\"},\"access\":{\"serviceType\":\"NodePort\"}}]" \
    --wait --timeout 5m

echo "== apply a NetApp"
kubectl apply -f - <<YAML
apiVersion: netapp.dev/v1alpha1
kind: NetApp
metadata: {name: e2e, namespace: ${APP_NS}}
spec:
  image: ${IMAGE}
  model:
    url: https://github.com/Megvii-BaseDetection/YOLOX/releases/download/0.1.1rc0/yolox_nano.onnx
    timeoutSeconds: 300
  resources: {cpu: 500m, memory: 768Mi}
YAML
kubectl -n "$APP_NS" wait netapp/e2e --for=condition=Ready --timeout=10m
URL="$(kubectl -n "$APP_NS" get netapp e2e -o jsonpath='{.status.url}')"
echo "== Ready at ${URL}"
curl --fail --silent --show-error --max-time 10 "${URL}/readyz" >/dev/null

echo "== stream a frame"
if [[ -n "$FRAME" ]]; then
    "$PY" -m netapp stream "$URL" --source "$FRAME" --transport http --fps 2 --duration 3 --json
else
    echo "no frame to stream (set NETAPP_E2E_FRAME)"; exit 1
fi

echo "== delete the NetApp; its children go with it"
kubectl -n "$APP_NS" delete netapp e2e --wait=true --timeout=2m
for _ in $(seq 60); do
    if [[ -z "$(kubectl -n "$APP_NS" get deployments,services -l app.kubernetes.io/instance=e2e -o name)" ]]; then
        echo "PASS"
        exit 0
    fi
    sleep 2
done
echo "FAIL: children of the deleted NetApp are still there"; exit 1
