"""How a netapp reaches the Kubernetes API for its camera Leases without a Kubernetes client (lease_api.py): where it
logs in, one line when it cannot, and a netapp that cannot still serves, pulling no camera."""

from __future__ import annotations

import logging

import pytest
import requests
import yaml

from netapp.server.settings import Settings
from netapp.server.sources import lease_api
from netapp.server.sources.lease_api import NO_LOGIN, lease_login
from netapp.server.sources.naming import parse_source


def kubeconfig(tmp_path, user: dict, cluster: dict | None = None) -> dict[str, str]:
    path = tmp_path / "kubeconfig"
    path.write_text(
        yaml.safe_dump(
            {
                "clusters": [{"name": "c", "cluster": {"server": "https://api.example:6443/", **(cluster or {})}}],
                "users": [{"name": "u", "user": user}],
                "contexts": [{"name": "x", "context": {"cluster": "c", "user": "u"}}],
                "current-context": "x",
            }
        )
    )
    return {"KUBECONFIG": str(path)}


def test_a_kubeconfigs_current_context_gives_the_server_its_tls_and_token(tmp_path):
    login = lease_login(kubeconfig(tmp_path, {"token": "s3cret"}, {"insecure-skip-tls-verify": True}))
    assert login.server == "https://api.example:6443" and login.verify is False
    assert login.headers() == {"Authorization": "Bearer s3cret"}
    token_file = tmp_path / "token"
    token_file.write_text("first\n")
    login = lease_login(kubeconfig(tmp_path, {"tokenFile": str(token_file)}))
    assert login.headers() == {"Authorization": "Bearer first"}
    token_file.write_text("rotated\n")  # the kubelet rotates bound tokens: read again for each request
    assert login.headers() == {"Authorization": "Bearer rotated"}


@pytest.mark.parametrize(
    "environ, words",
    [
        ({}, NO_LOGIN),
        ({"KUBERNETES_SERVICE_HOST": "10.96.0.1"}, "service account is not mounted"),
        ({"KUBECONFIG": "/nonexistent/kubeconfig"}, "cannot read the kubeconfig"),
    ],
)
def test_without_a_way_in_it_is_one_line(environ, words, tmp_path, monkeypatch):
    monkeypatch.setattr(lease_api, "SERVICE_ACCOUNT_DIR", tmp_path / "not-in-a-pod")
    with pytest.raises(ValueError, match=words.replace("$", r"\$").replace("(", r"\(").replace(")", r"\)")):
        lease_login(environ)


def test_an_exec_plugin_user_is_refused_in_one_line(tmp_path):
    with pytest.raises(ValueError, match="needs a token user"):
        lease_login(kubeconfig(tmp_path, {"exec": {"command": "aws"}}))


def test_a_netapp_that_cannot_reach_the_api_serves_says_so_once_and_pulls_nothing(
    serve, tiny_detector, monkeypatch, caplog
):
    monkeypatch.delenv("KUBECONFIG", raising=False)
    monkeypatch.delenv("KUBERNETES_SERVICE_HOST", raising=False)
    caplog.set_level(logging.ERROR, "netapp.server.sources.hub")
    settings = Settings(lanes=1, sources=(parse_source("door=rtsp://127.0.0.1:9/none"),), camera_leases="robots")
    server = serve(tiny_detector, settings)
    [line] = [r.getMessage() for r in caplog.records if r.name == "netapp.server.sources.hub"]
    assert line == f"{NO_LOGIN}; pulling no camera"
    assert requests.get(server.url + "/readyz", timeout=5).status_code == 200
