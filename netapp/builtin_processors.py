"""The processors that ship with netapp, by the name `netapp serve --processor NAME` takes.

Each builds a processor from the detector's configuration (the `--model`, `--labels`, `--conf`, `--iou` and
`--threads` options); the first is the default. Names are the catalogue's app names.
"""

from __future__ import annotations

from collections.abc import Callable

from netapp.models.detector import Detector, DetectorConfig
from netapp.sdk.processor import Processor


def object_detection(config: DetectorConfig) -> Processor:
    return Detector(config)


def object_tracking(config: DetectorConfig) -> Processor:
    from netapp.track.processor import TrackingDetector  # needs the `tracking` extra

    return TrackingDetector(config)


BUILTIN: dict[str, Callable[[DetectorConfig], Processor]] = {
    "object-detection": object_detection,
    "object-tracking": object_tracking,
}
DEFAULT = "object-detection"
# `trackers` asks for opencv-python, which would clash with opencv-python-headless: it is installed without it.
# The Makefile and the netapp images install the same (tests/chart/test_dockerfiles.py checks).
TRACKERS_REQUIREMENT = "trackers>=2.6.1,<2.7"
TRACKING_INSTALL = f"pip install 'netapp-toolkit[tracking]' && pip install --no-deps '{TRACKERS_REQUIREMENT}'"
