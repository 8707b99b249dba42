"""The uplink that adapts (issue 21): a pure controller that chooses what a robot sends (a frame's long side and
JPEG quality, or an H.264 bitrate, and the frame rate) from what each result says of the link, within a latency
budget and above an accuracy floor (`docs/client.md#an-uplink-that-adapts`)."""

from netapp.client.adapt.controller import AdaptConfig, Choice, Controller, Observation
from netapp.client.adapt.ladder import Ladder, Rung

__all__ = ["AdaptConfig", "Choice", "Controller", "Ladder", "Observation", "Rung"]
