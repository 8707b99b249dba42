"""Shared fixtures: tiny models built here, the real model and media from ../shared, servers on loopback."""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from tests.support.images import make_jpeg
from tests.support.onnx_models import TINY_BOX, TINY_NAMES, yolox_model
from tests.support.paths import SHARED
from tests.support.processors import GatedProcessor


def _shared_file(env: str, default: Path) -> Path | None:
    path = Path(os.environ[env]) if os.environ.get(env) else default
    return path if path.exists() else None


@pytest.fixture(scope="session")
def tiny_model_path(tmp_path_factory) -> Path:
    """A YOLOX-layout model (64x64 input, 3 classes) that always finds one `robot` at TINY_BOX."""
    return yolox_model(
        tmp_path_factory.mktemp("models") / "tiny_yolox.onnx",
        TINY_BOX,
        class_id=2,
        metadata={"names": str(dict(enumerate(TINY_NAMES)))},
    )


@pytest.fixture(scope="session")
def real_model_path() -> Path:
    path = _shared_file("NETAPP_TEST_MODEL", SHARED / "models" / "yolox_nano.onnx")
    if path is None:
        pytest.skip("the real YOLOX-Nano model is absent: set NETAPP_TEST_MODEL or put it at ../shared/models/")
    return path


@pytest.fixture(scope="session")
def media_dir() -> Path:
    path = _shared_file("NETAPP_TEST_MEDIA", SHARED / "media")
    if path is None:
        pytest.skip("the shared media are absent: set NETAPP_TEST_MEDIA or put them at ../shared/media/")
    return path


@pytest.fixture
def jpeg() -> bytes:
    return make_jpeg()


@pytest.fixture
def serve() -> Iterator[Callable]:
    """serve(processor, settings=None) -> a started BackgroundServer, stopped at teardown."""
    from netapp.server.app import create_app
    from netapp.server.runner import uvicorn_options
    from netapp.server.settings import Settings
    from tests.support.servers import BackgroundServer

    servers = []

    def start(processor, settings=None, ready_path="/readyz"):
        # One lane unless a test asks for more: a gated processor then holds the whole netapp, which is what the
        # tests of queueing, deadlines and back-pressure build on (the lanes have tests of their own).
        settings = settings or Settings(lanes=1)
        app = create_app(processor, settings)
        server = BackgroundServer(app, ready_path=ready_path, **uvicorn_options(settings)).start()
        servers.append(server)
        return server

    yield start
    for server in servers:
        server.stop()


@pytest.fixture
def tiny_detector(tiny_model_path):
    from netapp.models import Detector, DetectorConfig

    return Detector(DetectorConfig(str(tiny_model_path)))


@pytest.fixture
def tiny_server(serve, tiny_detector):
    return serve(tiny_detector)


@pytest.fixture
def profiled_tiny_server(serve, tiny_detector):
    """The tiny detector naming YOLOX-Nano's accuracy profile (its own model has none), for robots that adapt."""
    tiny_detector.load()
    tiny_detector.accuracy_profile = "yolox_nano"
    return serve(tiny_detector)


@pytest.fixture
def gated() -> GatedProcessor:
    processor = GatedProcessor()
    yield processor
    processor.gate.set()


@pytest.fixture
def chromium_with() -> Iterator[Callable[..., object]]:
    """chromium_with(*flags): Debian's chromium, headless, driven by Playwright, with more command-line flags (a fake
    camera, say); skips saying why where either is missing.

    Per test: Playwright's sync API keeps an event loop running in this thread while it is open, and a later
    test's asyncio.run() would refuse to start."""
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install playwright)")
    executable = shutil.which("chromium") or shutil.which("chromium-browser")
    if executable is None:
        pytest.skip("Debian's chromium is absent: apt-get install -y chromium (make system-deps does)")
    with sync_api.sync_playwright() as playwright:
        browsers = []

        def launch(*flags: str) -> object:
            browsers.append(playwright.chromium.launch(executable_path=executable, args=["--no-sandbox", *flags]))
            return browsers[-1]

        yield launch
        for browser in browsers:
            browser.close()


@pytest.fixture
def chromium(chromium_with) -> object:
    """Debian's chromium, headless (`chromium_with` with no more flags)."""
    return chromium_with()
