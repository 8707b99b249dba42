"""The cameras' fixtures: a real RTSP camera (GStreamer's RTSP server from Debian) per test, where it can run."""

from __future__ import annotations

import pytest

from netapp.serve_process import free_port
from tests.support.rtsp_camera import RtspCamera, gstreamer_problem


@pytest.fixture(scope="session")
def camera_tools() -> None:
    pytest.importorskip("av", reason="PyAV is not installed: pip install 'netapp-toolkit[h264]'")
    problem = gstreamer_problem()
    if problem:
        pytest.skip(problem)


@pytest.fixture
def cameras(camera_tools):
    """cameras(**size) -> a started RtspCamera on a free port, stopped at teardown."""
    started: list[RtspCamera] = []

    def start(**kwargs) -> RtspCamera:
        camera = RtspCamera(free_port(), **kwargs).start()
        started.append(camera)
        return camera

    yield start
    for camera in started:
        camera.stop()
