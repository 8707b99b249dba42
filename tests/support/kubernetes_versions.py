"""Kubernetes versions the project supports (README); rendered manifests are validated against each of them."""

KUBERNETES_VERSIONS = tuple(f"1.{minor}.0" for minor in range(27, 38))
