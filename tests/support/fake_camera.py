"""A fake camera for Debian's chromium (`--use-file-for-fake-video-capture`): a few seconds of a video as y4m, made
with FFmpeg; small, since y4m is raw video (640x360 at 10 fps: 3.5 MB a second)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

CAMERA_FLAGS = ("--use-fake-ui-for-media-stream", "--use-fake-device-for-media-stream")  # the permission, granted


def ffmpeg_problem() -> str | None:
    return None if shutil.which("ffmpeg") else "FFmpeg is absent: apt-get install -y ffmpeg (make system-deps does)"


def fake_camera(video: Path, out: Path, seconds: float = 2.0, size: str = "640:360") -> Path:
    """`seconds` of `video` at `size`, 10 fps, as the y4m chromium's fake camera plays in a loop."""
    command = ["ffmpeg", "-loglevel", "error", "-y", "-i", str(video), "-t", str(seconds), "-r", "10"]
    subprocess.run([*command, "-vf", f"scale={size}", "-pix_fmt", "yuv420p", str(out)], check=True, timeout=60)
    return out


def camera_flags(y4m: Path) -> list[str]:
    """chromium's flags for a camera that plays `y4m`."""
    return [*CAMERA_FLAGS, f"--use-file-for-fake-video-capture={y4m}"]
