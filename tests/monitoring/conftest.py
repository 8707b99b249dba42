# Fixtures other test folders define, reused here: helm (fetched from PyPI or skipped), and the middleware started
# in this process on a backend (with its robots file).
from tests.chart.conftest import helm  # noqa: F401
from tests.middleware.conftest import robots_file, start_middleware  # noqa: F401
