"""Where the checkout and the shared models and media are (one place for every test and benchmark)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SHARED = ROOT.parent / "shared"
