"""Backends: where NetApps actually run. One module per backend, all behind `Backend` (see base.py)."""

from .base import Backend, InstanceState, StateCallback

__all__ = ["Backend", "InstanceState", "StateCallback"]
