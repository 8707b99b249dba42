"""Kubernetes operator: reconciles NetApp and NodePool custom resources into placed, healthy Deployments.

The pure parts (placement, render, status, validate) import nothing from Kubernetes libraries and are unit-tested
without a cluster; `handlers` wires them to kopf, `kube` is the thin I/O layer.
"""

GROUP = "netapp.dev"
VERSION = "v1alpha1"
API_VERSION = f"{GROUP}/{VERSION}"
MANAGER = "netapp-operator"
# Kubernetes versions the project supports (README); rendered manifests are validated against each of them.
KUBERNETES_VERSIONS = tuple(f"1.{minor}.0" for minor in range(27, 38))
