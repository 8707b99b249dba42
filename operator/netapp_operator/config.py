"""Operator settings: one frozen object built from CLI flags (or defaults in tests)."""

from __future__ import annotations

import dataclasses

DEFAULT_IMAGE = "ghcr.io/netapp-toolkit/netapp:0.1.0"
# curl with --max-time bounds a stalled download (KServe's storage initializer hangs forever); sha256sum comes
# from the image's busybox. The image runs as a non-root user.
DEFAULT_MODEL_INIT_IMAGE = "curlimages/curl:8.11.1"
# The netapp server needs --model: a NetApp without `model` gets this one (YOLOX-Nano, COCO, Apache-2.0).
DEFAULT_MODEL_URL = "https://github.com/Megvii-BaseDetection/YOLOX/releases/download/0.1.1rc0/yolox_nano.onnx"
DEFAULT_MODEL_SHA256 = "d39bee73564e338080378b0ad567fbb40e818b55bbfaf971de82a0267ed16b8a"


@dataclasses.dataclass(frozen=True)
class OperatorConfig:
    namespaces: tuple[str, ...] = ()  # empty: all namespaces
    failover_grace_seconds: float = 30.0  # how long a pool may have no ready nodes before its netapps move
    check_interval_seconds: float = 5.0  # how often placement (failover, pending netapps) and pool status are checked
    model_init_image: str = DEFAULT_MODEL_INIT_IMAGE
    default_model_url: str = DEFAULT_MODEL_URL  # empty: a NetApp without `model` gets no --model argument
    default_model_sha256: str = DEFAULT_MODEL_SHA256
    liveness_endpoint: str | None = None  # e.g. http://0.0.0.0:8080/healthz
    watch_server_timeout: int = 300  # asks the API server to end each watch after this many seconds
    watch_client_timeout: int = 330  # drops a watch that the server keeps silent for longer
    watch_connect_timeout: int = 30
    run_as_user: int = 10001  # the uid of the netapp images (see the Dockerfiles)

    @property
    def clusterwide(self) -> bool:
        return not self.namespaces
