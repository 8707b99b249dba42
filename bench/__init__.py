"""Benchmarks (not shipped): run each as `python -m bench.NAME` from the repository root (bench/README.md)."""
