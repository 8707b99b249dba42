# Fixtures other test folders define, reused here: helm (fetched from PyPI or skipped), the middleware started in this
# process on a backend (with its robots file), and the Kubernetes emulator with a client of it.
from tests.chart.conftest import helm  # noqa: F401
from tests.middleware.conftest import robots_file, start_middleware  # noqa: F401
from tests.operator.conftest import api, emulator  # noqa: F401
