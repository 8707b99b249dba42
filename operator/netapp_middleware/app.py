"""The FastAPI application: shared services on `app.state`, thin routers in `routers/`."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field

from fastapi import FastAPI

from .auth import RobotRegistry, TokenSigner
from .catalogue import Catalogue
from .deployments import Registry
from .login_guard import LoginGuard


@dataclass
class Services:
    registry: Registry
    robots: RobotRegistry
    signer: TokenSigner
    catalogue: Callable[[], Catalogue]
    max_wait_s: float = 60.0
    # era-5g-client never refreshes its token, yet needs it to follow a switchover and to delete its plan at the end.
    era_token_ttl_s: float = 24 * 3600.0
    logins: LoginGuard = field(default_factory=LoginGuard)


def create_app(services: Services) -> FastAPI:
    from .routers import apps, auth, deployments, era, health

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        await services.registry.start()
        try:
            yield
        finally:
            await services.registry.close()

    app = FastAPI(title="netapp middleware", version="0.1.0", lifespan=lifespan)
    app.state.services = services
    for module in (health, auth, apps, deployments, era):
        app.include_router(module.router)
    return app
