"""An IP camera on loopback: GStreamer's RTSP server (Debian's gir1.2-gst-rtsp-server-1.0 and python3-gi) serving a
live test picture as H.264 at rtsp://127.0.0.1:PORT/cam. It needs Debian's /usr/bin/python3 (PyGObject is not in the
venv), so tests run it as its own process: `RtspCamera` below; `python3 rtsp_camera.py PORT WIDTH HEIGHT FPS`."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

SYSTEM_PYTHON = "/usr/bin/python3"
INSTALL_HINT = "apt-get install gir1.2-gst-rtsp-server-1.0 python3-gi gstreamer1.0-plugins-ugly (make system-deps)"
READY = "ready"


def gstreamer_problem() -> str | None:
    """Why no camera can run here (the install hint), or None."""
    if not Path(SYSTEM_PYTHON).exists() or shutil.which("gst-launch-1.0") is None:
        return f"GStreamer's RTSP server is absent: {INSTALL_HINT}"
    probe = "import gi; gi.require_version('GstRtspServer', '1.0'); from gi.repository import GstRtspServer"
    if subprocess.run([SYSTEM_PYTHON, "-c", probe], capture_output=True, timeout=30).returncode != 0:
        return f"GStreamer's RTSP server cannot be imported by {SYSTEM_PYTHON}: {INSTALL_HINT}"
    return None


class RtspCamera:
    """with RtspCamera(port) as camera: ... camera.url ...; stop() and start() again to take it away and back."""

    def __init__(self, port: int, width: int = 320, height: int = 240, fps: int = 15) -> None:
        self.port, self.size, self.fps = port, (width, height), fps
        self.url = f"rtsp://127.0.0.1:{port}/cam"
        self.process: subprocess.Popen | None = None

    def start(self) -> RtspCamera:
        args = [SYSTEM_PYTHON, __file__, str(self.port), *map(str, self.size), str(self.fps)]
        self.process = subprocess.Popen(args, stdout=subprocess.PIPE, text=True)
        line = self.process.stdout.readline().strip()  # blocks until the server is attached, or the process ends
        if line != READY:
            self.stop()
            raise RuntimeError(f"the RTSP camera did not start (it said {line!r})")
        return self

    def stop(self) -> None:
        if self.process is not None:
            self.process.terminate()
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
            self.process.stdout.close()
            self.process = None

    def __enter__(self) -> RtspCamera:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def main(port: str, width: str, height: str, fps: str) -> None:
    import gi

    gi.require_version("Gst", "1.0")
    gi.require_version("GstRtspServer", "1.0")
    from gi.repository import GLib, Gst, GstRtspServer

    Gst.init(None)
    server = GstRtspServer.RTSPServer()
    server.set_address("127.0.0.1")
    server.set_service(port)
    factory = GstRtspServer.RTSPMediaFactory()
    # A keyframe a second (key-int-max), the SPS and PPS with each (config-interval): a viewer joins within a second.
    factory.set_launch(
        f"( videotestsrc is-live=true pattern=ball ! video/x-raw,width={width},height={height},framerate={fps}/1 "
        f"! x264enc tune=zerolatency speed-preset=ultrafast key-int-max={fps} ! rtph264pay name=pay0 pt=96 "
        "config-interval=-1 )"
    )
    factory.set_shared(True)  # one encoder for every viewer, as a camera has
    server.get_mount_points().add_factory("/cam", factory)
    if server.attach(None) == 0:
        sys.exit(f"cannot listen on 127.0.0.1:{port}")
    print(READY, flush=True)
    GLib.MainLoop().run()


if __name__ == "__main__":
    main(*sys.argv[1:5])
