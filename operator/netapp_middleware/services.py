"""What every request of the middleware shares: its registry, robots, token signer and catalogue (no FastAPI here,
so the app, the dependencies and the routers all import this and nothing imports back)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from .auth import RobotRegistry, TokenSigner
from .catalogue import Catalogue
from .deployments import Registry
from .login_guard import LoginGuard
from .model_rollouts import ModelRollouts
from .switchover import Switchover
from .tracing import DeploymentTraces

if TYPE_CHECKING:
    from netapp_operator.kube import Kube

    from netapp.tracing import Tracer


@dataclass
class Services:
    registry: Registry
    robots: RobotRegistry
    signer: TokenSigner
    catalogue: Callable[[], Catalogue]
    max_wait_s: float = 60.0
    # era-5g-client never refreshes its token, yet needs it to follow a switchover and to delete its plan at the end.
    era_token_ttl_s: float = 24 * 3600.0
    kube: Kube | None = None  # the Kubernetes client of the backend and the sources, closed with the app
    # The dashboard's people: their own credentials (never a robot's) and their own token key (a robot's token is
    # no operator's session).
    operators: RobotRegistry = field(default_factory=lambda: RobotRegistry(dict))
    operator_signer: TokenSigner = field(default_factory=lambda: TokenSigner(ttl_s=8 * 3600.0))
    logins: LoginGuard = field(default_factory=LoginGuard)  # what logins may cost (login_guard)
    # Moves robots between placements on their latency reports; the default one between edge and cloud.
    switchover: Switchover = field(default=None)  # type: ignore[assignment]
    # Where deployments' traces go (docs/tracing.md); None: tracing is off.
    tracer: Tracer | None = None
    traces: DeploymentTraces | None = field(init=False, default=None)
    # Rollouts of the models the catalogue changes, on the running netapps (the local backend's; model_rollouts.py)
    rollouts: ModelRollouts = field(default=None)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if self.switchover is None:
            self.switchover = Switchover(self.registry, self.catalogue)
        if self.rollouts is None:
            self.rollouts = ModelRollouts(self.registry, self.catalogue)
        if self.tracer is not None:
            self.traces = DeploymentTraces(self.tracer)
