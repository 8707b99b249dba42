"""Operator settings: one frozen object built from CLI flags (or defaults in tests)."""

from __future__ import annotations

import dataclasses

from netapp_operator.constants import DEFAULT_MODEL_SHA256, DEFAULT_MODEL_URL, MODEL_CACHE_DIR, MODEL_INIT_IMAGE
from netapp_operator.webrtc import WebRtcSpec


@dataclasses.dataclass(frozen=True)
class OperatorConfig:
    namespaces: tuple[str, ...] = ()  # empty: all namespaces
    failover_grace_seconds: float = 30.0  # how long a pool may have no ready nodes before its netapps move
    check_interval_seconds: float = 5.0  # how often placement (failover, pending netapps) and pool status are checked
    model_init_image: str = MODEL_INIT_IMAGE
    # Each node's cache of the models its pods fetched, by sha256 (netapp_operator.model_fetch); empty: none.
    model_cache_dir: str = MODEL_CACHE_DIR
    prepull_namespace: str = ""  # where NodePools' pre-pull DaemonSets go; empty: the operator's own namespace
    # The netapp server needs --model: a NetApp without `model` gets this one.
    default_model_url: str = DEFAULT_MODEL_URL  # empty: a NetApp without `model` gets no --model argument
    default_model_sha256: str = DEFAULT_MODEL_SHA256
    liveness_endpoint: str | None = None  # e.g. http://0.0.0.0:8080/healthz
    metrics_endpoint: str | None = None  # e.g. http://0.0.0.0:8082/metrics (netapp_operator.metrics)
    watch_server_timeout: int = 300  # asks the API server to end each watch after this many seconds
    watch_client_timeout: int = 330  # drops a watch that the server keeps silent for longer
    watch_connect_timeout: int = 30
    reconcile_workers: int = 32  # NetApps reconciled at once (a burst of thousands waits in the work queue)
    run_as_user: int = 10001  # the uid of the netapp images (see the Dockerfiles)
    # Model rollouts (docs/rollouts.md#kubernetes): the token the operator starts them with (the netapps get its
    # SHA-256); empty: no rollouts, a changed model restarts the pods with it.
    rollout_token: str = dataclasses.field(default="", repr=False)
    rollout_poll_seconds: float = 5.0  # how often a running rollout's netapp is asked how it goes
    rollout_timeout_seconds: float = 5.0  # one request to a netapp, connect to last byte
    idle_poll_seconds: float = 5.0  # how often the pods of a NetApp with spec.scaling.idleToZero are asked for robots
    # The waker (netapp_operator.waker): the operator's pod IP it listens on and sleeping NetApps' Services send
    # robots to; empty: no waker (a sleeping NetApp's Service refuses connections).
    waker_ip: str = ""
    waker_port: int = 8083
    # The `spec.webrtc` of NetApps without one (--ice-server, --turn-secret): None, no STUN or TURN server is named.
    default_webrtc: WebRtcSpec | None = None

    @property
    def clusterwide(self) -> bool:
        return not self.namespaces
