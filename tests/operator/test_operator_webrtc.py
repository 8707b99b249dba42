"""A NetApp's `spec.webrtc`: its ICE servers in the netapp's args, a TURN server's credentials from the Secret in the
environment (never the args); what is wrong with it, said in one sentence; the CRD's schema."""

from __future__ import annotations

import jsonschema
import pytest
from netapp_operator.spec import parse

from tests.operator.test_operator_render import kinds, netapp, pool, render
from tests.operator.test_operator_rtp import NETAPP_SCHEMA


def container(**webrtc) -> dict:
    made = kinds(render(netapp(webrtc=webrtc), pool()))
    return made["Deployment"]["spec"]["template"]["spec"]["containers"][0]


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
