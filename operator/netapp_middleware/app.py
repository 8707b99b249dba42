"""The FastAPI application: shared services (services.py) on `app.state`, thin routers in `routers/`, and every
error answered with the one body of `netapp.protocol.error_body`."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator

from fastapi import FastAPI

from netapp import http_errors

from .routers import apps, auth, dashboard, deployments, era, health, metrics, standbys
from .services import Services


def create_app(services: Services) -> FastAPI:
    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        await services.registry.start()
        services.switchover.start()
        services.rollouts.start()
        try:
            yield
        finally:
            await services.rollouts.close()
            await services.switchover.close()
            await services.registry.close()
            if services.kube is not None:
                await services.kube.close()

    app = FastAPI(title="netapp middleware", version="0.1.0", lifespan=lifespan)
    http_errors.install(app)
    app.state.services = services
    for module in (health, metrics, auth, apps, deployments, era, dashboard, standbys):
        app.include_router(module.router)
    return app
