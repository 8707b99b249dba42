"""The real-cluster end-to-end script (tools/e2e-cluster.sh), run when a cluster is given."""

from __future__ import annotations

import os
import subprocess

import pytest

from tests.chart.chart_helpers import ROOT

pytestmark = [
    pytest.mark.cluster,
    pytest.mark.timeout(1200),
    pytest.mark.skipif(
        not (os.environ.get("KUBECONFIG") and os.environ.get("NETAPP_E2E_CLUSTER") == "1"),
        reason="real-cluster test: set KUBECONFIG and NETAPP_E2E_CLUSTER=1 to run it",
    ),
]


def test_chart_netapp_frame_delete_on_a_real_cluster():
    result = subprocess.run([str(ROOT / "tools" / "e2e-cluster.sh")], capture_output=True, text=True, timeout=1150)
    assert result.returncode == 0 and "PASS" in result.stdout, result.stdout + result.stderr
