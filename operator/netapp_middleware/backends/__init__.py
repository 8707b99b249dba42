"""Backends: where NetApps actually run. One module per backend, all behind `Backend` (see base.py)."""

from .base import Backend, Claim, InstanceState, Recovered, StateCallback

__all__ = ["Backend", "Claim", "InstanceState", "Recovered", "StateCallback"]
