"""The 5G-ERA heartbeat: every second a running netapp tells its middleware how many robots it serves and how many
it can (`{"id", "name", "currentRobotsCount", "optimalLimit", "hardLimit"}` POSTed to
`{MIDDLEWARE_ADDRESS}/status/netapp`), so the middleware can place the next robot elsewhere. The limits come from
the measured capacity (`netapp.server.capacity`); before it is measured they assume `Settings.assumed_robot_fps`.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from netapp.server.services import NetAppServices

log = logging.getLogger(__name__)

HEARTBEAT_PATH = "/status/netapp"
PERIOD_S = 1.0
TIMEOUT_S = 2.0


def heartbeat_body(services: NetAppServices) -> dict[str, Any]:
    limits = services.capacity()
    return {
        "id": services.settings.netapp_id,
        "name": services.settings.netapp_name,
        "currentRobotsCount": len(services.sessions),
        "optimalLimit": limits.optimal,
        "hardLimit": limits.hard,
    }


async def send_heartbeats(services: NetAppServices, period_s: float = PERIOD_S) -> None:
    """POST the heartbeat every `period_s` until cancelled; a middleware that does not answer is logged once per
    outage, and the netapp carries on serving."""
    url = services.settings.middleware_address.rstrip("/") + HEARTBEAT_PATH
    import requests  # here: a netapp without a middleware starts without it

    failing = False
    with requests.Session() as http:
        while True:
            try:
                response = await asyncio.to_thread(http.post, url, json=heartbeat_body(services), timeout=TIMEOUT_S)
                response.raise_for_status()
                if failing:
                    log.info("heartbeats reach %s again", url)
                failing = False
            except requests.RequestException as exc:
                if not failing:
                    log.warning("heartbeat to %s failed (%s); retrying every %.0f s", url, exc, period_s)
                failing = True
            await asyncio.sleep(period_s)
