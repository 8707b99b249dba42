"""A camera's password never leaves the netapp: cameras with credentials that fail in every way FFmpeg can fail (a
401, a refused connection, nonsense, silence), their passwords plain and percent-encoded, and every output grepped
(the log at DEBUG, FFmpeg's own stderr, /metrics, the live page and its API, a watcher's acknowledgement)."""

from __future__ import annotations

import logging

import requests

from netapp.serve_process import free_port
from tests.netapp.server.sources.test_cameras import READER_LOG, settings_for
from tests.netapp.server.test_frames import metric
from tests.support.fake_cameras import HostileCamera, RefusingCamera
from tests.support.polling import wait_until
from tests.support.watcher import Watcher

PLAIN = "S3cr3tPw1"
ENCODED = "p%40ss%2Fw0rd"  # p@ss/w0rd
SECRETS = (PLAIN, ENCODED, "p@ss/w0rd", "p%40ss", "w0rd")


def test_credentials_never_reach_a_log_a_page_a_metric_or_an_event(camera_tools, serve, tiny_detector, caplog, capfd):
    caplog.set_level(logging.DEBUG)
    refusing, junk, silent = (
        RefusingCamera(),
        HostileCamera(b"HTTP/1.0 200 OK\r\n\r\n" + b"\xff" * 999),
        HostileCamera(),
    )
    ports = {"refusing": refusing.port, "junk": junk.port, "silent": silent.port, "closed": free_port()}
    sources = [
        f"{n}{i}=rtsp://admin:{pw}@127.0.0.1:{p}/cam" for n, p in ports.items() for i, pw in enumerate(SECRETS[:2])
    ]
    try:
        server = serve(tiny_detector, settings_for(*sources))

        def told() -> set[str]:
            return {r.getMessage().split(":")[0] for r in caplog.records if r.name == READER_LOG}

        wait_until(lambda: len(told()) == len(sources), 30, "every camera to be told unreachable")
        outputs = [r.getMessage() for r in caplog.records] + [str(r.exc_info) for r in caplog.records if r.exc_info]
        outputs += [requests.get(server.url + path, timeout=10).text for path in ("/metrics", "/ui", "/ui/api/robots")]
        with Watcher(server.url, "refusing0"):  # its acknowledgement says whether the camera is up: never how
            wait_until(lambda: metric(server.url, 'netapp_source_subscribers{source="refusing0"}') == 1, 10, "it")
        server.stop()
        captured = capfd.readouterr()
        outputs += [captured.out, captured.err]
    finally:
        for camera in (refusing, junk, silent):
            camera.close()
    lines = [r.getMessage() for r in caplog.records if r.name == READER_LOG]
    assert any("401" in line for line in lines) and any("refused" in line.lower() for line in lines), lines
    assert any("rtsp://***@127.0.0.1" in line for line in lines), lines  # where the camera was, not who
    for secret in SECRETS:
        leaks = [o for o in outputs if secret in o]
        assert not leaks, (secret, leaks[0][:300])
