"""`netapp serve`'s start-up: without the cyclic collector until it can serve, and without the modules it does not
serve with (docs/benchmarks.md#cold-start)."""

from __future__ import annotations

import argparse
import gc
import subprocess
import sys

import pytest

from netapp.server import cli
from netapp.startup import collector_paused, deferred


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
    """httpx (a cluster's forwarding and revocation, cameras' Leases), PyAV (the first H.264 stream), requests (a
    model's download, the 5G-ERA heartbeat), YAML (a kubeconfig) and what python-socketio imports for its clients
    (aiohttp, websocket-client) and its AMQP manager (aio_pika) are imported or run when first used: a netapp that
    needs none of them starts ~300 ms sooner. The app is built, as `netapp serve` builds it before it listens."""
    code = (
        "import sys; import netapp.server.cli, netapp.server.runner; "
        "from netapp.server.decoding.h264 import H264Decoder; H264Decoder(); "
        "from netapp.server.app import create_app; from tests.support.processors import GatedProcessor; "
        "create_app(GatedProcessor()); "
        "unused = ('httpx', 'av', 'rich', 'requests', 'urllib3', 'yaml', 'aiohttp', 'aiormq', 'websocket'); "
        "print(' '.join(m for m in unused if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == []


def test_a_deferred_library_runs_when_first_read_and_a_missing_one_still_fails(tmp_path, monkeypatch) -> None:
    (tmp_path / "deferred_lib.py").write_text("VALUE = 42\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "deferred_lib", raising=False)
    with deferred("deferred_lib", "no_such_library_here"):
        import deferred_lib  # type: ignore[import-not-found]

        with pytest.raises(ImportError):
            import no_such_library_here  # type: ignore[import-not-found]  # noqa: F401
    assert "deferred_lib" not in sys.modules  # not run; importing it now imports it as usual
    assert deferred_lib.VALUE == 42 and sys.modules["deferred_lib"].VALUE == 42
    with deferred("deferred_lib"):  # already imported: itself
        import deferred_lib as again  # type: ignore[import-not-found]
    assert again is sys.modules["deferred_lib"]
