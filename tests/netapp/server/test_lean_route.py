"""POST /send_image runs on a lean route (netapp/server/http/lean_route.py): it reads `wait` as FastAPI did, answers
as the FastAPI route did, and /openapi.json still describes it."""

from __future__ import annotations

import requests


def test_the_frame_route_reads_wait_and_answers_as_fastapi_did(tiny_server, jpeg):
    url = tiny_server.url
    sid = requests.post(f"{url}/register", timeout=5).json()["session_id"]
    headers = {"X-Session-Id": sid, "Content-Type": "image/jpeg", "X-Timestamp": "7"}

    def post(wait: str | None) -> requests.Response:
        params = {"wait": wait} if wait is not None else None
        return requests.post(f"{url}/send_image", params=params, data=jpeg, headers=headers, timeout=10)

    for word in ("true", "Yes", "1", "on"):
        r = post(word)
        assert r.status_code == 200 and r.json()["timestamp"] == 7, (word, r.text)
    for word in (None, "false", "no", "0"):
        r = post(word)
        assert r.status_code == 202 and r.json() == {"timestamp": 7, "queued": True}, (word, r.text)
    r = post("maybe")
    assert r.status_code == 422 and r.json()["reason"] == "invalid_request" and "query.wait" in r.json()["error"]


def test_openapi_still_describes_the_frame_route(tiny_server):
    spec = requests.get(f"{tiny_server.url}/openapi.json", timeout=5).json()["paths"]["/send_image"]["post"]
    assert spec["operationId"] == "send_image_send_image_post"
    names = {p["name"] for p in spec["parameters"]}
    assert {"wait", "x-timestamp", "X-Deadline-Ms", "X-Robot-Latency", "authorization", "x-session-id"} <= names
    assert {"200", "202"} <= spec["responses"].keys()
