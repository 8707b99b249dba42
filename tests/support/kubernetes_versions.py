"""Kubernetes versions the project supports (docs/kubernetes.md); rendered manifests are validated against each."""

KUBERNETES_VERSIONS = tuple(f"1.{minor}.0" for minor in range(27, 38))
