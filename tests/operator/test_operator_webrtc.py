"""A NetApp's `spec.webrtc`: its ICE servers in the netapp's args, a TURN server's credentials from the Secret in the
environment (never the args); what is wrong with it, said in one sentence; the CRD's schema; the operator's default
(`--ice-server`, `--turn-secret`: the chart's `operator.webrtc`) for NetApps without one."""

from __future__ import annotations

import argparse
import subprocess
import sys

import jsonschema
import pytest
from netapp_operator.cli import add_arguments, config_from_args
from netapp_operator.config import OperatorConfig
from netapp_operator.spec import parse

from tests.operator.test_operator_render import kinds, netapp, pool, render
from tests.operator.test_operator_rtp import NETAPP_SCHEMA


def container(**webrtc) -> dict:
    made = kinds(render(netapp(webrtc=webrtc), pool()))
    return made["Deployment"]["spec"]["template"]["spec"]["containers"][0]


def operator_config(*flags: str) -> OperatorConfig:
    """The config `netapp operator FLAGS` runs with (its own parser)."""
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return config_from_args(parser.parse_args(list(flags)))


def ice(made: dict) -> tuple[list[str], dict]:
    """(the --ice-server URLs, the NETAPP_ICE_* variables' sources) of a rendered netapp container."""
    args = made["args"]
    urls = [args[i + 1] for i, a in enumerate(args) if a == "--ice-server"]
    return urls, {e["name"]: e.get("valueFrom") for e in made["env"] if e["name"].startswith("NETAPP_ICE")}


def test_ice_servers_reach_the_args_and_turn_credentials_the_environment():
    made = container(iceServers=["stun:stun.example.org:3478", "turn:turn.example.org:3478"], turnSecret="turn")
    args = made["args"]
    assert [args[i + 1] for i, a in enumerate(args) if a == "--ice-server"] == [
        "stun:stun.example.org:3478",
        "turn:turn.example.org:3478",
    ]
    env = {e["name"]: e.get("valueFrom") for e in made["env"]}
    assert env["NETAPP_ICE_USERNAME"] == {"secretKeyRef": {"name": "turn", "key": "username"}}
    assert env["NETAPP_ICE_CREDENTIAL"] == {"secretKeyRef": {"name": "turn", "key": "credential"}}


def test_without_webrtc_no_ice_server_is_named():
    made = kinds(render(netapp(), pool()))["Deployment"]["spec"]["template"]["spec"]["containers"][0]
    assert "--ice-server" not in made["args"]
    assert not any(e["name"].startswith("NETAPP_ICE") for e in made["env"])


@pytest.mark.parametrize(
    ("webrtc", "says"),
    [
        ({"iceServers": ["turn:turn.example.org"]}, "turnSecret"),
        ({"iceServers": ["http://turn.example.org"]}, "stun:HOST"),
        ({"iceServers": ["turn:user:pw@turn.example.org"], "turnSecret": "t"}, "never in the URL"),
        ({"iceServers": [3478]}, "URLs"),
        ({"iceServers": ["stun:s"] * 9}, "at most 8"),
    ],
)
def test_what_is_wrong_is_one_sentence(webrtc, says):
    problems = [p for p in parse({"image": "i", "webrtc": webrtc}).problems if "webrtc" in p]
    assert len(problems) == 1 and says in problems[0], problems


def test_the_crd_takes_ice_servers_and_refuses_credentials_in_a_url():
    spec = NETAPP_SCHEMA["schema"]["openAPIV3Schema"]["properties"]["spec"]
    good = {"image": "i", "webrtc": {"iceServers": ["turn:turn.example.org:3478"], "turnSecret": "turn"}}
    jsonschema.validate(good, spec)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({"image": "i", "webrtc": {"iceServers": ["turn:u:p@turn.example.org"]}}, spec)


TURN_DEFAULT = ("--ice-server", "turn:turn.example.org:3478", "--turn-secret", "cluster-turn")


def test_the_operators_default_reaches_netapps_without_spec_webrtc():
    made = kinds(render(netapp(), pool(), operator_config(*TURN_DEFAULT)))
    urls, env = ice(made["Deployment"]["spec"]["template"]["spec"]["containers"][0])
    assert urls == ["turn:turn.example.org:3478"]
    assert env["NETAPP_ICE_CREDENTIAL"] == {"secretKeyRef": {"name": "cluster-turn", "key": "credential"}}


@pytest.mark.parametrize(
    ("webrtc", "urls"),
    [
        ({"iceServers": ["stun:stun.example.org"]}, ["stun:stun.example.org"]),  # its own, whole: no default Secret
        ({}, []),  # `webrtc: {}`: this NetApp names none, whatever the default
    ],
)
def test_a_netapps_own_spec_webrtc_wins_whole(webrtc, urls):
    made = kinds(render(netapp(webrtc=webrtc), pool(), operator_config(*TURN_DEFAULT)))
    found_urls, env = ice(made["Deployment"]["spec"]["template"]["spec"]["containers"][0])
    assert found_urls == urls and not env


def test_no_default_names_no_server():
    assert operator_config().default_webrtc is None


@pytest.mark.parametrize(
    ("flags", "says"),
    [
        (("--ice-server", "turn:turn.example.org"), "operator.webrtc names a TURN server: give turnSecret"),
        (("--ice-server", "turn:u:p@turn.example.org", "--turn-secret", "t"), "never in the URL"),
        (("--ice-server", "http://turn.example.org"), "stun:HOST"),
    ],
)
def test_a_wrong_default_is_one_line_naming_the_flags(flags, says):
    with pytest.raises(ValueError, match="--ice-server/--turn-secret") as caught:
        operator_config(*flags)
    assert says in str(caught.value) and "\n" not in str(caught.value)


def test_netapp_operator_refuses_a_wrong_default_at_its_start_in_one_line():
    cmd = [sys.executable, "-m", "netapp", "operator", "--ice-server", "turn:turn.example.org:3478"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert lines[0].startswith("netapp operator: --ice-server/--turn-secret: operator.webrtc names a TURN server")
