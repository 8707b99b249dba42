"""Maintainer scripts (not shipped): fetching helm/kubectl/hadolint, rendering manifests/, the chart's values table."""
