"""A camera's picture size is checked before FFmpeg decodes at it: a stream claiming 7680x4320 is refused in one line
with the process's memory where it was (FFmpeg's probe, given the bound, decodes nothing over it)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

MEASURE = """
import sys
import av
from prometheus_client import CollectorRegistry
from netapp.server.errors import FrameRejected
from netapp.server.sources.metrics import SourceMetrics
from netapp.server.settings import SourceSpec
from netapp.server.sources.reader import CameraReader

av.open(sys.argv[2]).close()  # FFmpeg's own start-up, before the baseline
metrics = SourceMetrics(CollectorRegistry())
metrics.add("big")
reader = CameraReader(SourceSpec("big", sys.argv[1]), lambda *a: None, metrics, 640 * 480, 1 << 20)
def peak_kb():
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith("VmHWM:"))
with open("/proc/self/clear_refs", "w") as refs:
    refs.write("5")  # the peak starts again from here (Linux)
before = peak_kb()
try:
    reader._read()
except FrameRejected as exc:
    print(exc)
print((peak_kb() - before) // 1024)
"""


def h264_file(path: str, width: int, height: int) -> str:
    import av

    with av.open(path, "w") as out:
        stream = out.add_stream("libx264", rate=10, options={"preset": "ultrafast", "tune": "zerolatency"})
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        picture = av.VideoFrame.from_ndarray(np.zeros((height, width, 3), np.uint8), format="bgr24")
        for packet in [*stream.encode(picture), *stream.encode()]:
            out.mux(packet)
    return path


def test_a_stream_claiming_8k_is_refused_before_ffmpeg_decodes_at_it(tmp_path):
    pytest.importorskip("av", reason="PyAV is not installed: pip install 'netapp-toolkit[h264]'")
    big = h264_file(str(tmp_path / "8k.mkv"), 7680, 4320)
    small = h264_file(str(tmp_path / "small.mkv"), 64, 64)
    run = subprocess.run([sys.executable, "-c", MEASURE, big, small], capture_output=True, text=True, timeout=120)
    refusal, grew_mb = run.stdout.strip().splitlines()
    assert "7680x4320 = 33177600 pixels is over this netapp's limit of 307200" in refusal, run.stderr[-2000:]
    assert int(grew_mb) < 40  # measured: 10 MB; decoding at the probe, as before: 75 MB (16000x16000: 1.4 GB)
