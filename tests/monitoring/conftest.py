from tests.chart.conftest import helm  # noqa: F401 (the chart tests' helm, fetched from PyPI or skipped)
