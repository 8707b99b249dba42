"""Where robots and apps come from: files (re-read when changed), a Secret and a ConfigMap; the CLI's helpers."""

from __future__ import annotations

import base64
import json
import os
import re
from pathlib import Path
from typing import Any

import pytest
import yaml
from netapp_middleware.auth import AuthError, hash_secret, verify_secret
from netapp_middleware.server import build_services
from netapp_middleware.switchover.decision import SwitchPolicy

from netapp.cli import build_parser, main
from tests.support.paths import ROOT

CUSTOM = {
    "apps": {
        "segmentation": {
            "description": "d",
            "taskId": "11111111-2222-4333-8444-555555555555",
            "spec": {"image": "example.org/seg:1", "port": 8000},
        }
    }
}


def args(*argv: str) -> Any:
    return build_parser().parse_args(["middleware", *argv])


def test_hash_secret_command(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["middleware", "hash-secret", "hunter2"]) == 0
    hashed = capsys.readouterr().out.strip()
    assert hashed.startswith("scrypt$") and verify_secret("hunter2", hashed)


def test_files_are_reread_when_they_change(tmp_path: Path) -> None:
    robots, catalogue = tmp_path / "robots.yaml", tmp_path / "catalogue.yaml"
    robots.write_text(yaml.safe_dump({"robots": {"r1": hash_secret("one", n=2**10)}}))
    catalogue.write_text(yaml.safe_dump(CUSTOM))
    services = build_services(args("--robots-file", str(robots), "--catalogue-file", str(catalogue)))
    services.robots.authenticate("r1", "one")
    assert set(services.catalogue().apps) == {"segmentation"}
    assert services.catalogue().by_task_id("11111111-2222-4333-8444-555555555555").name == "segmentation"
    # A rotated secret (a Secret volume is swapped in place) takes effect without a restart.
    robots.write_text(yaml.safe_dump({"robots": {"r1": hash_secret("two", n=2**10), "r2": hash_secret("x", n=2**10)}}))
    os.utime(robots, (1, 1))  # a different mtime even within the filesystem's timestamp granularity
    with pytest.raises(AuthError):
        services.robots.authenticate("r1", "one")
    services.robots.authenticate("r1", "two")
    assert services.robots.known("r2")


def test_a_malformed_file_fails_at_start(tmp_path: Path) -> None:
    robots = tmp_path / "robots.yaml"
    robots.write_text(yaml.safe_dump({"r1": "plain text"}))
    with pytest.raises(ValueError, match="scrypt"):
        build_services(args("--robots-file", str(robots)))


def test_default_catalogue_and_token_key(tmp_path: Path) -> None:
    key = tmp_path / "key"
    key.write_bytes(b"a key shared by replicas, 32 bytes or more\n")
    one = build_services(args("--token-key-file", str(key)))
    two = build_services(args("--token-key-file", str(key)))
    token, _ = one.signer.issue("r1")
    assert two.signer.verify(token).robot_id == "r1"  # a restarted middleware accepts the old tokens
    assert "object-detection" in one.catalogue().apps


def test_robots_secret_and_catalogue_configmap(kube_api: Any) -> None:
    import anyio

    robots_yaml = yaml.safe_dump({"robots": {"r1": hash_secret("one", n=2**10)}})
    secret = {
        "apiVersion": "v1",
        "kind": "Secret",
        "metadata": {"name": "robots", "namespace": "mw"},
        "data": {"robots.yaml": base64.b64encode(robots_yaml.encode()).decode()},
    }
    configmap = {
        "apiVersion": "v1",
        "kind": "ConfigMap",
        "metadata": {"name": "apps", "namespace": "mw"},
        "data": {"apps.yaml": yaml.safe_dump(CUSTOM)},
    }
    kube_api.run(kube_api.kube.create(secret))
    kube_api.run(kube_api.kube.create(configmap))

    async def serve() -> None:
        services = build_services(
            args("--namespace", "mw", "--robots-secret", "robots", "--catalogue-configmap", "apps:apps.yaml"),
            kube=kube_api.new_kube(),
        )

        def route() -> None:  # where the app reads them: its routes' worker threads
            services.robots.authenticate("r1", "one")
            assert set(services.catalogue().apps) == {"segmentation"}

        await anyio.to_thread.run_sync(route)
        await services.kube.close()

    anyio.run(serve)


def test_the_charts_catalogue_and_robots_are_in_the_middlewares_formats() -> None:
    """The Helm chart writes catalogue.yaml and robots.yaml from its values: the middleware must read them, and the
    chart.s apps must be the built-in ones (same 5G-ERA task ids, args and model)."""
    from netapp_middleware.auth import parse_robots
    from netapp_middleware.catalogue import DEFAULT_CATALOGUE, parse_catalogue

    values = yaml.safe_load((ROOT / "charts" / "netapp-toolkit" / "values.yaml").read_text())
    charts, builtin = parse_catalogue(values["catalogue"]), parse_catalogue(DEFAULT_CATALOGUE)
    assert set(charts.apps) == set(builtin.apps) == {"object-detection", "object-tracking"}
    for name, app in charts.apps.items():  # the same task ids, processor, args and model as the built-in catalogue
        same = builtin.apps[name]
        assert app.task_id == same.task_id and app.spec["model"] == same.spec["model"]
        assert app.spec.get("processor") == same.spec.get("processor")
        assert app.spec.get("args", []) == same.spec.get("args", [])
    # what an app serves is its spec's processor, which both backends honour, never a flag hidden in its args
    for app in [*charts.apps.values(), *builtin.apps.values()]:
        assert not any(str(a).startswith("--processor") for a in app.spec.get("args", [])), app.name
    assert builtin.apps["object-tracking"].spec["processor"] == "object-tracking"
    items = [{"id": "robot-1", "secretHash": hash_secret("x", n=2**10)}]
    assert set(parse_robots({"robots": items})) == {"robot-1"}
    assert parse_robots({"robots": values["robots"]["items"]}) == {}
    schema = json.loads((ROOT / "charts" / "netapp-toolkit" / "values.schema.json").read_text())
    pattern = schema["properties"]["robots"]["properties"]["items"]["items"]["properties"]["secretHash"]["pattern"]
    assert re.match(pattern, items[0]["secretHash"])  # what hash-secret prints passes the chart's schema


def test_switchover_flags(tmp_path: Path) -> None:
    services = build_services(
        args(
            "--switchover-placements",
            "edge-a, cloud",
            "--switchover-sustain",
            "3",
            "--switchover-warm-sustain",
            "0.5",
            "--switchover-dwell",
            "60",
        )
    )
    switchover = services.switchover
    assert switchover.placements == ["edge-a", "cloud"] and switchover.enabled
    assert (switchover.policy.sustain_s, switchover.policy.warm_sustain_s, switchover.policy.min_dwell_s) == (
        3.0,
        0.5,
        60.0,
    )
    default = build_services(args()).switchover.policy
    assert default.warm_sustain_s == SwitchPolicy().warm_sustain_s  # the flag's default is the policy's
    assert not build_services(args("--switchover-placements", "edge")).switchover.enabled
    with pytest.raises(ValueError, match="'Edge_1' is no placement"):
        build_services(args("--switchover-placements", "Edge_1,cloud"))
