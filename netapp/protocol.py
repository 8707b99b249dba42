"""Names and numbers of the 5G-ERA wire protocol, shared by the server and the robot client (no server code)."""

from __future__ import annotations

from enum import IntEnum

DATA_NAMESPACE = "/data"
CONTROL_NAMESPACE = "/control"
COMMAND_EVENT = "command"
COMMAND_ERROR_EVENT = "command_error"
DATA_ERROR_EVENT = "data_error"
RESULTS_EVENT = "results"
IMAGE_EVENT = "image"
H264_EVENT = "image_h264"
DEFAULT_PORT = 5896
# How a robot sends frames: HTTP POSTs of JPEGs, Socket.IO `image` events (JPEG), Socket.IO `image_h264` events.
TRANSPORTS = ("http", "ws", "h264")
# `reason` of a data_error after which an H.264 sender should restart its stream with a keyframe at once: the
# netapp's decoder lost the stream and would otherwise refuse packets until the next periodic keyframe.
H264_KEYFRAME_REASONS = frozenset(
    {"h264_decode_error", "h264_missing_packet", "h264_no_picture", "h264_waiting_keyframe", "h264_overloaded"}
)


class CommandType(IntEnum):
    INIT = 1
    RESET_STATE = 2
    GET_STATE = 3
    SET_STATE = 4
    SAVE_STATE = 5
    LOAD_STATE = 6
