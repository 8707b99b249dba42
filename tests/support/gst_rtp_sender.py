"""A robot's own GStreamer pipeline sending H.264 over RTP (Debian's gst-launch-1.0, its own process): the line
docs/cameras.md#rtp-push gives robot teams, with the port and SSRC the netapp answered."""

from __future__ import annotations

import shutil
import subprocess

INSTALL_HINT = (
    "install Debian's GStreamer: sudo apt-get install gstreamer1.0-tools gstreamer1.0-plugins-good "
    "gstreamer1.0-plugins-ugly (or sudo make system-deps)"
)


def gst_problem() -> str | None:
    """Why no GStreamer sender can run here (the install hint), or None."""
    if shutil.which("gst-launch-1.0") is None:
        return f"gst-launch-1.0 is absent: {INSTALL_HINT}"
    for element in ("x264enc", "rtph264pay", "udpsink"):
        if subprocess.run(["gst-inspect-1.0", element], capture_output=True, timeout=30).returncode != 0:
            return f"GStreamer's {element} is absent: {INSTALL_HINT}"
    return None


def pipeline(port: int, ssrc: int, width: int = 320, height: int = 240, fps: int = 10, key_int: int = 30) -> list[str]:
    """gst-launch-1.0's arguments: a moving ball, x264 zero-latency, RTP to the netapp on loopback."""
    line = (
        f"videotestsrc is-live=true pattern=ball ! video/x-raw,width={width},height={height},framerate={fps}/1 "
        f"! x264enc tune=zerolatency speed-preset=ultrafast key-int-max={key_int} "
        f"! rtph264pay config-interval=1 pt=96 ssrc={ssrc} ! udpsink host=127.0.0.1 port={port}"
    )
    return ["gst-launch-1.0", "-q", *line.split()]


class GstRtpSender:
    """with GstRtpSender(port, ssrc): ... (stopped at the end)."""

    def __init__(self, port: int, ssrc: int, **options: int) -> None:
        self.args = pipeline(port, ssrc, **options)
        self.process: subprocess.Popen | None = None

    def __enter__(self) -> GstRtpSender:
        self.process = subprocess.Popen(self.args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        return self

    def __exit__(self, *exc: object) -> None:
        if self.process is not None:
            self.process.terminate()
            try:
                self.process.wait(5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(5)
