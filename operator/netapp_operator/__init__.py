"""Kubernetes operator: reconciles NetApp and NodePool custom resources into placed, healthy Deployments.

The pure parts (placement, render, status, spec) import nothing from Kubernetes libraries and are unit-tested
without a cluster; `handlers` wires them to kopf, `kube` is the one Kubernetes client (kubernetes_asyncio, shared with
the middleware); names and defaults live in `constants`.
"""
