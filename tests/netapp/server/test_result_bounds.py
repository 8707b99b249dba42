"""A custom processor's masks, keypoints and oriented boxes leave the netapp as it made them when they fit their
bounds; one too big or malformed is refused (the box still goes), counted by reason on /metrics, never sent; a
result's classifications are cut to their bound."""

from __future__ import annotations

import re
from collections import Counter

import requests

from netapp.results import MAX_CLASSIFICATIONS, bound_result
from tests.support.images import make_jpeg
from tests.support.result_processors import HOSTILE_FIELDS, HostileProcessor, SceneProcessor, scene


def send_and_wait(url: str, jpeg: bytes) -> dict:
    session = requests.post(f"{url}/register", json={}, timeout=5).json()["session_id"]
    response = requests.post(
        f"{url}/send_image",
        params={"wait": "true"},
        data=jpeg,
        headers={"X-Session-Id": session, "Content-Type": "image/jpeg"},
        timeout=10,
    )
    assert response.status_code == 200, response.text
    return response.json()


def refused_on_metrics(url: str) -> dict[str, float]:
    text = requests.get(f"{url}/metrics", timeout=5).text
    found = re.findall(r'^netapp_result_fields_refused_total\{reason="(\w+)"\} (\S+)$', text, re.M)
    return {reason: float(value) for reason, value in found}


def test_fields_that_fit_are_sent_as_the_processor_made_them(serve):
    server = serve(SceneProcessor())
    result = send_and_wait(server.url, make_jpeg(160, 120))
    expected = scene(160, 120)
    assert result["detections"] == expected["detections"]
    assert result["classifications"] == expected["classifications"]
    assert refused_on_metrics(server.url) == {}


def test_fields_too_big_or_malformed_are_refused_counted_and_never_sent(serve):
    server = serve(HostileProcessor())
    result = send_and_wait(server.url, make_jpeg(160, 120))
    *bad, fine = result["detections"]
    assert len(bad) == len(HOSTILE_FIELDS)
    for detection, (name, _, reason) in zip(bad, HOSTILE_FIELDS, strict=True):
        assert name not in detection, reason  # the field is gone
        assert detection["bbox"] == [1.0, 1.0, 9.0, 9.0] and detection["class_name"] == "bicycle"  # the box is not
    assert fine == scene(160, 120)["detections"][0]  # the good detection beside them is whole
    assert len(result["classifications"]) == MAX_CLASSIFICATIONS
    expected = Counter(reason for _, _, reason in HOSTILE_FIELDS)
    expected["too_many_classifications"] = 7
    assert refused_on_metrics(server.url) == {k: float(v) for k, v in expected.items()}
    send_and_wait(server.url, make_jpeg(160, 120))
    assert refused_on_metrics(server.url)["mask_too_big"] == 2 * expected["mask_too_big"]  # per result


def test_bound_result_copies_only_what_it_changes():
    fine = scene(64, 48)
    assert bound_result(fine) == (fine, []) and bound_result(fine)[0] is fine
    out, refused = bound_result({"classifications": "top-5", "other": 1})
    assert out == {"other": 1} and refused == ["classifications_malformed"]
