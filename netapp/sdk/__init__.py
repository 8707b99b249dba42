"""The netapp SDK: package any per-frame algorithm as a netapp.

Implement a `Processor` and hand it to `serve()` (or `create_app()`): the framework gives it sessions, the HTTP,
Socket.IO (5G-ERA) and H.264 transports, frame decoding, newest-frame-wins queues, batching across robots,
health and Prometheus metrics. A `StatefulProcessor` also keeps a state per robot session (e.g. a tracker),
which the 5G-ERA state commands and the robot client's checkpoints move between netapps.

    from netapp.sdk import Processor, serve

    class Blur(Processor):
        name = "blur-score"
        def prepare(self, image, args):
            return image
        def process(self, batch):
            return [{"sharpness": float(cv2.Laplacian(img, cv2.CV_64F).var())} for img in batch]

    serve(Blur(), port=5896)
"""

from netapp.protocol import DEFAULT_PORT
from netapp.sdk.processor import Processor, StatefulProcessor
from netapp.sdk.state import StateError
from netapp.server.settings import Settings  # stdlib only: the server's dependencies load with create_app

__all__ = ["Processor", "Settings", "StateError", "StatefulProcessor", "create_app", "serve"]


def create_app(processor: Processor, settings: Settings | None = None):
    """The ASGI application serving `processor` (see `netapp.server.app.create_app`)."""
    from netapp.server.app import create_app as _create_app

    return _create_app(processor, settings)


def serve(
    processor: Processor, host: str = "127.0.0.1", port: int = DEFAULT_PORT, settings: Settings | None = None
) -> None:
    """Run `processor` as a netapp with uvicorn until interrupted."""
    from netapp.server.runner import run_server

    run_server(processor, host=host, port=port, settings=settings)
