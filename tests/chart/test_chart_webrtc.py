"""The chart's `operator.webrtc` (docs/cameras.md#webrtc): no STUN or TURN server by default; when set, flags the
operator's own parser takes as the default `spec.webrtc` of NetApps without one; a TURN server without its Secret,
or credentials in a URL, refused by the values schema."""

from __future__ import annotations

import pytest
from netapp_operator.webrtc import WebRtcSpec

from tests.chart.chart_helpers import CHART, run, template
from tests.operator.test_operator_webrtc import operator_config


def operator_args(objects: list[dict]) -> list[str]:
    [dep] = [o for o in objects if o["kind"] == "Deployment" and o["metadata"]["name"].endswith("-operator")]
    args = dep["spec"]["template"]["spec"]["containers"][0]["args"]
    return args[args.index("operator") + 1 :]


def test_no_ice_server_by_default_and_the_values_reach_the_operator(helm):
    assert operator_config(*operator_args(template(helm))).default_webrtc is None
    values = CHART / "ci" / "edge-cloud-gpu-values.yaml"
    assert operator_config(*operator_args(template(helm, values))).default_webrtc == WebRtcSpec(
        ("turn:turn.robots.example.com:3478",), "turn-credentials"
    )


@pytest.mark.parametrize(
    ("values", "message"),
    [
        # (the chart's default turnSecret "" is merged in: what is refused is its length)
        ("operator: {webrtc: {iceServers: ['turn:turn.example.org']}}", "/operator/webrtc/turnSecret"),
        (
            "operator: {webrtc: {iceServers: ['turn:u:p@turn.example.org'], turnSecret: t}}",
            "/operator/webrtc/iceServers/0",
        ),
        ("operator: {webrtc: {iceServers: ['http://stun.example.org']}}", "/operator/webrtc/iceServers/0"),
        ("operator: {webrtc: {turnSecret: Not_A_Name}}", "/operator/webrtc/turnSecret"),
    ],
)
def test_values_schema_refuses_a_turn_server_without_its_secret_or_with_credentials(helm, tmp_path, values, message):
    path = tmp_path / "values.yaml"
    path.write_text(values + "\n")
    result = run(helm, "template", "x", CHART, "--values", path, check=False)
    assert result.returncode != 0 and message in result.stderr, result.stderr


def test_a_stun_server_alone_needs_no_secret(helm, tmp_path):
    path = tmp_path / "values.yaml"
    path.write_text("operator: {webrtc: {iceServers: ['stun:stun.example.org:3478']}}\n")
    config = operator_config(*operator_args(template(helm, path)))
    assert config.default_webrtc == WebRtcSpec(("stun:stun.example.org:3478",), None)
