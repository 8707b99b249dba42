"""`/unregister` revokes a token on every replica: another replica serving its `wait=true` frames asks the owner and
refuses it from then on (two in-process replicas sharing a key)."""

from __future__ import annotations

import requests

from netapp.serve_process import free_port
from netapp.server.app import create_app
from netapp.server.cluster.revocation import RevocationCheck
from netapp.server.runner import uvicorn_options
from netapp.server.settings import Settings
from tests.support.images import make_jpeg
from tests.support.servers import BackgroundServer

KEY = b"r" * 32


def _replica(detector) -> BackgroundServer:
    port = free_port()
    settings = Settings(lanes=1, cluster_key=KEY, advertise_url=f"http://127.0.0.1:{port}")
    app = create_app(detector, settings)
    app.services.revocations = RevocationCheck(
        app.services.cluster, app.services.peers, every_s=0.0
    )  # ask the owner on every frame
    return BackgroundServer(app, port=port, **uvicorn_options(settings)).start()


def _frame(url: str, token: str) -> requests.Response:
    headers = {"X-Session-Id": token, "X-Timestamp": "1", "Content-Type": "image/jpeg"}
    return requests.post(f"{url}/send_image?wait=true", data=make_jpeg(), headers=headers, timeout=10)


def test_unregister_revokes_the_token_on_every_replica(tiny_detector):
    owner, other = _replica(tiny_detector), _replica(tiny_detector)
    try:
        token = requests.post(f"{owner.url}/register", json={"robot_id": "r"}, timeout=10).json()["session_id"]
        assert _frame(other.url, token).status_code == 200  # processed where it lands, a record on `other`
        assert requests.post(f"{other.url}/unregister", headers={"X-Session-Id": token}, timeout=10).ok  # forwarded
        refused = _frame(other.url, token)
        assert refused.status_code == 404 and refused.json()["reason"] == "unknown_session"
        assert _frame(owner.url, token).status_code == 404
    finally:
        other.stop()
        owner.stop()
