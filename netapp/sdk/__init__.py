"""The netapp SDK: the contract a per-frame algorithm is written against to be packaged as a netapp.

Implement a `Processor` and hand it to `netapp.server.serve()` (or `create_app()`): the framework gives it sessions,
every way in (HTTP, Socket.IO as 5G-ERA, `frames`, RTP, WebRTC, the RTSP cameras it pulls), frame decoding,
newest-frame-wins queues, batching across robots, health and Prometheus metrics. A `StatefulProcessor` also keeps a
state per robot session (e.g. a tracker), which the 5G-ERA state commands and the robot client's checkpoints move
between netapps.

    from netapp.sdk import Processor
    from netapp.server import serve

    class Blur(Processor):
        name = "blur-score"
        def prepare(self, image, args):
            return image
        def process(self, batch):
            return [{"sharpness": float(cv2.Laplacian(img, cv2.CV_64F).var())} for img in batch]

    serve(Blur(), port=5896)

A processor returns its detections as `netapp.sdk.Detection`s (a box, and a `Mask`, keypoints or an oriented box
where it has them) or `Classification`s, converted with `netapp.results.to_wire`: the same fields the built-in
models send (netapp/results.py), bounded by the netapp before they leave.

This package imports nothing from `netapp.server`: the contract stands alone.
"""

from netapp.results import Classification, Detection, Mask
from netapp.sdk.processor import Processor, StatefulProcessor
from netapp.sdk.session_state import StateError

__all__ = ["Classification", "Detection", "Mask", "Processor", "StateError", "StatefulProcessor"]
