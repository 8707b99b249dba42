"""The HTTP routes, one module per concern."""

from __future__ import annotations

from fastapi import APIRouter

from netapp.server.http.routes import frames, health, metrics, rollout, sessions, state_commands, webrtc

ROUTERS: tuple[APIRouter, ...] = (
    sessions.router,
    frames.router,
    state_commands.router,
    health.router,
    metrics.router,
    rollout.router,
    webrtc.router,
)
