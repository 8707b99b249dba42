"""A camera's password never leaves the netapp: cameras with credentials that fail in every way FFmpeg can fail (a
401, a refused connection, nonsense, silence), their passwords plain and percent-encoded, and every output grepped
(the log at DEBUG, FFmpeg's own stderr, /metrics, the live page and its API, a watcher's acknowledgement)."""

from __future__ import annotations

import contextlib
import logging
import socket
import threading

import requests

from netapp.serve_process import free_port
from tests.netapp.server.sources.test_cameras import READER_LOG, HostileCamera, settings_for
from tests.netapp.server.test_frames import metric
from tests.support.polling import wait_until
from tests.support.watcher import Watcher

PLAIN = "S3cr3tPw1"
ENCODED = "p%40ss%2Fw0rd"  # p@ss/w0rd
SECRETS = (PLAIN, ENCODED, "p@ss/w0rd", "p%40ss", "w0rd")
UNAUTHORIZED = b'RTSP/1.0 401 Unauthorized\r\n%s\r\nWWW-Authenticate: Basic realm="cam"\r\n\r\n'


class RefusingCamera:
    """Answers each RTSP request 401 Unauthorized, as a camera given the wrong password does."""

    def __init__(self) -> None:
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.server.accept()
            except OSError:
                return
            threading.Thread(target=self._answer, args=(conn,), daemon=True).start()

    @staticmethod
    def _answer(conn: socket.socket) -> None:
        with conn, contextlib.suppress(OSError):
            while request := conn.recv(4096):
                cseq = next((line for line in request.split(b"\r\n") if line.lower().startswith(b"cseq")), b"CSeq: 1")
                conn.sendall(UNAUTHORIZED % cseq)

    def close(self) -> None:
        self.server.close()


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
