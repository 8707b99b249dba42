"""The HTTP transport: register, send, wait, poll, unregister; every bad input gets its clear error."""

from __future__ import annotations

import threading

import pytest
import requests

from netapp.protocol import RESULT_STAMPS
from netapp.server.settings import Settings
from tests.support.attacks import corrupt_jpeg
from tests.support.images import make_jpeg
from tests.support.onnx_models import TINY_NAMES

RESULT_KEYS = {"timestamp", *RESULT_STAMPS, "detections"}


def register(url: str, **body) -> str:
    response = requests.post(f"{url}/register", json=body or None, timeout=5)
    assert response.status_code == 201, response.text
    return response.json()["session_id"]


def send(url, sid, data, wait=True, timestamp=None, content_type="image/jpeg"):
    headers = {"X-Session-Id": sid, "Content-Type": content_type}
    if timestamp is not None:
        headers["X-Timestamp"] = str(timestamp)
    return requests.post(
        f"{url}/send_image", params={"wait": str(wait).lower()}, data=data, headers=headers, timeout=10
    )


def test_register_send_wait_poll_unregister(tiny_server, jpeg):
    url = tiny_server.url
    sid = register(url, robot_id="r1", args={"anything": 1})
    r = send(url, sid, jpeg, wait=True, timestamp=123)
    assert r.status_code == 200, r.text
    result = r.json()
    assert RESULT_KEYS <= result.keys() and result["timestamp"] == 123
    assert (
        result["recv_timestamp"]
        <= result["timestamp_before_process"]
        <= result["timestamp_after_process"]
        <= result["send_timestamp"]
    )
    (d,) = result["detections"]
    assert d["class_name"] == TINY_NAMES[2] and d["class"] == 2 and len(d["bbox"]) == 4

    r = send(url, sid, jpeg, wait=False, timestamp=124)
    assert r.status_code == 202 and r.json()["timestamp"] == 124
    polled = []
    for _ in range(200):  # poll with a deadline
        polled += requests.get(f"{url}/results", headers={"X-Session-Id": sid}, timeout=5).json()["results"]
        if polled:
            break
        threading.Event().wait(0.02)
    assert [p["timestamp"] for p in polled] == [124]
    assert requests.get(f"{url}/results", headers={"X-Session-Id": sid}, timeout=5).json()["results"] == []

    r = requests.post(f"{url}/unregister", headers={"X-Session-Id": sid}, timeout=5)
    assert r.status_code == 200 and r.json()["processed"] == 2
    assert send(url, sid, jpeg).status_code == 404


def test_register_without_body_and_with_bad_json(tiny_server):
    assert requests.post(f"{tiny_server.url}/register", timeout=5).status_code == 201
    r = requests.post(f"{tiny_server.url}/register", data=b"{not json", timeout=5)
    assert r.status_code == 422 and "JSON" in r.json()["error"]
    r = requests.post(f"{tiny_server.url}/register", json={"args": "not a mapping"}, timeout=5)
    assert r.status_code == 422


@pytest.mark.parametrize("prepare_threads", [0, 2], ids=["decode-on-inference-thread", "decode-pool"])
def test_bad_input_gets_clear_errors_and_harms_no_other_robot(serve, tiny_detector, jpeg, prepare_threads):
    server = serve(tiny_detector, Settings(max_payload_bytes=50_000, prepare_threads=prepare_threads))
    url = server.url
    victim = register(url, robot_id="victim")
    other = register(url, robot_id="steady")
    stop = threading.Event()
    steady_results, steady_failures = [], []

    def steady_robot():
        ts = 0
        while not stop.is_set():
            ts += 1
            r = send(url, other, jpeg, timestamp=ts)
            (steady_results if r.status_code == 200 else steady_failures).append(r.status_code)

    thread = threading.Thread(target=steady_robot)
    thread.start()
    try:
        cases = [
            (send(url, victim, corrupt_jpeg()), 400, "corrupt JPEG"),
            (send(url, victim, b"GIF89a...."), 400, "not a JPEG"),
            (send(url, victim, b""), 400, "empty"),
            (send(url, victim, jpeg, content_type="text/plain"), 415, "Content-Type"),
            (send(url, victim, b"\xff\xd8\xff" + b"\x00" * 60_000), 413, "limit"),
            (send(url, "no-such-session", jpeg), 404, "unknown session"),
            (
                requests.post(
                    f"{url}/send_image",
                    data=jpeg,
                    headers={"X-Session-Id": victim, "X-Timestamp": "abc", "Content-Type": "image/jpeg"},
                    timeout=5,
                ),
                422,
                "integer",
            ),
        ]
        for response, status, text in cases:
            assert response.status_code == status, (text, response.text)
            assert text in response.json()["error"]
        assert send(url, victim, jpeg).status_code == 200  # the victim's session still works
    finally:
        stop.set()
        thread.join()
    assert steady_failures == [] and len(steady_results) > 0
    metrics = requests.get(f"{url}/metrics", timeout=5).text
    for reason in ("bad_frame", "wrong_content_type", "payload_too_large", "unknown_session", "bad_timestamp"):
        assert f'netapp_frames_rejected_total{{reason="{reason}",transport="http"}}' in metrics


def test_every_error_body_says_what_and_why(tiny_server, jpeg):
    """One body for every answer that is not 2xx: `error` (what to do), `reason` (a stable code), context."""
    url = tiny_server.url
    sid = register(url)
    answers = {
        "unknown_session": requests.get(f"{url}/results", headers={"X-Session-Id": "nope"}, timeout=5),
        "wrong_content_type": send(url, sid, jpeg, timestamp=5, content_type="text/plain"),
        "invalid_request": requests.post(f"{url}/register", data=b"{not json", timeout=5),
        "unknown_model": requests.get(f"{url}/v2/models/nope", timeout=5),
        "not_found": requests.get(f"{url}/no/such/path", timeout=5),
        "method_not_allowed": requests.post(f"{url}/results", timeout=5),
    }
    for reason, response in answers.items():
        body = response.json()
        assert response.status_code >= 400 and body["reason"] == reason and body["error"], (reason, body)
    assert answers["unknown_session"].json()["session_id"] == "nope"
    assert answers["wrong_content_type"].json()["timestamp"] == "5"


def test_health_readiness_model_metadata_and_metrics(tiny_server, jpeg):
    url = tiny_server.url
    assert requests.get(f"{url}/healthz", timeout=5).json() == {"status": "live"}
    assert requests.get(f"{url}/v2/health/live", timeout=5).status_code == 200
    assert requests.get(f"{url}/readyz", timeout=5).status_code == 200
    assert requests.get(f"{url}/v2/health/ready", timeout=5).status_code == 200
    meta = requests.get(f"{url}/v2/models/tiny_yolox", timeout=5).json()
    assert meta["layout"] == "yolox" and meta["classes"] == 3
    assert requests.get(f"{url}/v2/models/other", timeout=5).status_code == 404
    sid = register(url)
    assert send(url, sid, jpeg).status_code == 200
    metrics = requests.get(f"{url}/metrics", timeout=5).text
    assert 'netapp_frames_received_total{transport="http"} 1.0' in metrics
    assert 'netapp_frames_processed_total{transport="http"} 1.0' in metrics
    assert 'netapp_active_sessions{transport="http"} 1.0' in metrics
    assert 'netapp_latency_seconds_count{transport="http"} 1.0' in metrics
    assert "netapp_inference_seconds_count" in metrics and "netapp_queue_depth 0.0" in metrics


def test_not_ready_until_loaded(serve, gated, jpeg):
    class SlowLoad(type(gated)):
        def load(self):
            assert self.gate.wait(30)

    slow = SlowLoad()
    server = serve(slow, ready_path=None)
    url = server.url
    assert requests.get(f"{url}/healthz", timeout=5).status_code == 200
    r = requests.get(f"{url}/readyz", timeout=5)
    assert r.status_code == 503 and "loading" in r.json()["error"]
    sid = register(url)
    r = send(url, sid, jpeg)
    assert r.status_code == 503 and "loading" in r.json()["error"]
    slow.gate.set()


def test_newest_frame_wins_and_drops_are_counted(serve, gated):
    server = serve(gated)
    url = server.url
    sid = register(url)
    first = []
    t = threading.Thread(target=lambda: first.append(send(url, sid, make_jpeg(), timestamp=1)))
    t.start()
    assert gated.entered.acquire(timeout=10)  # frame 1 is being processed; the queue holds one more
    waiting = []
    threads = []
    for ts in (2, 3, 4):
        th = threading.Thread(target=lambda ts=ts: waiting.append((ts, send(url, sid, make_jpeg(), timestamp=ts))))
        th.start()
        threads.append(th)
        for _ in range(500):  # each frame must be queued before the next one supersedes it
            if requests.get(f"{url}/metrics", timeout=5).text.count(
                f'netapp_frames_received_total{{transport="http"}} {ts}.0'
            ):
                break
            threading.Event().wait(0.01)
    # 2 and 3 were superseded by 4 while 1 was processed: 409 without waiting for the gate
    for th in threads[:2]:
        th.join(timeout=10)
    gated.gate.set()
    t.join(timeout=10)
    threads[2].join(timeout=10)
    status = {ts: r.status_code for ts, r in waiting}
    assert first[0].status_code == 200
    assert status == {2: 409, 3: 409, 4: 200}
    assert "newest frame wins" in dict(waiting)[2].json()["error"]
    assert dict(waiting)[2].json()["reason"] == "superseded" and dict(waiting)[2].json()["timestamp"] == 2
    assert dict(waiting)[4].json()["dropped"] == 2
    assert 'netapp_frames_dropped_total{transport="http"} 2.0' in requests.get(f"{url}/metrics", timeout=5).text


@pytest.mark.parametrize("prepare_threads", [0, 2], ids=["decode-on-inference-thread", "decode-pool"])
def test_a_corrupt_frame_sent_without_waiting_is_reported(serve, tiny_detector, jpeg, prepare_threads):
    url = serve(tiny_detector, Settings(prepare_threads=prepare_threads)).url
    sid = register(url)
    r = send(url, sid, corrupt_jpeg(), wait=False, timestamp=7)
    if r.status_code == 400:  # decoded on receipt: refused at once
        assert prepare_threads and "corrupt JPEG" in r.json()["error"]
        return
    assert r.status_code == 202 and not prepare_threads
    for _ in range(200):  # decoded on the inference thread: the error takes the result's place
        polled = requests.get(f"{url}/results", headers={"X-Session-Id": sid}, timeout=5).json()["results"]
        if polled:
            break
        threading.Event().wait(0.02)
    assert polled == [{"timestamp": 7, "error": polled[0]["error"], "reason": "bad_frame"}]
    assert "corrupt JPEG" in polled[0]["error"]


def test_results_a_robot_never_polls_are_bounded_and_counted(serve, tiny_detector, jpeg):
    url = serve(tiny_detector, Settings(results_buffer=2)).url
    sid = register(url)
    for ts in range(1, 5):
        assert send(url, sid, jpeg, wait=True, timestamp=ts).status_code == 200  # processed, result to caller
    for ts in range(5, 9):  # 202 each; the previous one is processed before the next is sent
        assert send(url, sid, jpeg, wait=False, timestamp=ts).status_code == 202
        for _ in range(500):
            metrics = requests.get(f"{url}/metrics", timeout=5).text
            if f'netapp_frames_processed_total{{transport="http"}} {ts}.0' in metrics:
                break
            threading.Event().wait(0.01)
    body = requests.get(f"{url}/results", headers={"X-Session-Id": sid}, timeout=5).json()
    assert [r["timestamp"] for r in body["results"]] == [7, 8]  # only the newest two were kept
    assert body["results_overflowed"] == 2
    assert "netapp_results_overflowed_total 2.0" in requests.get(f"{url}/metrics", timeout=5).text
