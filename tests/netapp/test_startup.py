"""`netapp serve`'s start-up: without the cyclic collector until it can serve, and without the modules it does not
serve with (docs/benchmarks.md#cold-start)."""

from __future__ import annotations

import argparse
import gc
import subprocess
import sys

import pytest

from netapp.server import cli
from netapp.startup import collector_paused


def test_the_collector_is_paused_in_the_block_then_frozen_and_back_on() -> None:
    assert gc.isenabled()
    frozen = gc.get_freeze_count()
    try:
        with collector_paused():
            assert not gc.isenabled()
            made = [[] for _ in range(1000)]
            with collector_paused():  # nested: leaves it as it found it (off)
                pass
            assert not gc.isenabled()
        assert gc.isenabled() and gc.get_freeze_count() > frozen and made
        gc.disable()
        with collector_paused():  # already off: stays off after
            pass
        assert not gc.isenabled()
    finally:
        gc.enable()
        gc.unfreeze()
    with pytest.raises(RuntimeError), collector_paused():
        raise RuntimeError("a failed start-up")
    assert gc.isenabled()
    gc.unfreeze()


def test_serve_prepares_with_the_collector_paused_and_serves_with_it_on(monkeypatch: pytest.MonkeyPatch) -> None:
    seen: dict[str, bool] = {}

    def prepare(args: argparse.Namespace) -> tuple[object, object]:
        seen["prepare"] = gc.isenabled()
        return object(), object()

    def serve(*args: object, **kwargs: object) -> None:
        seen["serve"] = gc.isenabled()

    monkeypatch.setattr(cli, "prepare", prepare)
    monkeypatch.setattr("netapp.server.runner.serve", serve)
    args = argparse.Namespace(host="127.0.0.1", port=1, log_level="WARNING", tls_cert=None, tls_key=None)
    try:
        assert cli.run(args) == 0
    finally:
        gc.unfreeze()
    assert seen == {"prepare": False, "serve": True}


def test_serve_imports_no_http_client_and_no_video_codec_it_does_not_serve_with() -> None:
    """httpx (a cluster's forwarding and revocation, cameras' Leases) and PyAV (the first H.264 stream) are imported
    when first used: a netapp that needs neither starts ~90 ms sooner."""
    code = (
        "import sys; import netapp.server.cli, netapp.server.runner; "
        "from netapp.server.decoding.h264 import H264Decoder; H264Decoder(); "
        "print(' '.join(m for m in ('httpx', 'av', 'rich') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == []
