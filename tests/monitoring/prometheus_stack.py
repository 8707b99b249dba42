"""Debian's Prometheus and Alertmanager on loopback for the monitoring tests, and the webhook receiver the
Alertmanager notifies: real processes with short scrape, evaluation and grouping intervals, stopped at the end."""

from __future__ import annotations

import contextlib
import json
import pathlib
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import requests
import yaml

from netapp.serve_process import free_port, wait_http_ok
from tests.monitoring.monitoring_helpers import program

MAX_NOTIFICATION_BYTES = 1 << 20  # an Alertmanager notification of a few alerts is a few kB


class Webhook:
    """An HTTP receiver of Alertmanager's webhook notifications (JSON), on loopback."""

    def __init__(self) -> None:
        self.notifications: list[dict[str, Any]] = []
        self.changed = threading.Condition()
        hook = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:  # noqa: N802 (http.server's name)
                length = int(self.headers.get("Content-Length") or 0)
                if not 0 < length <= MAX_NOTIFICATION_BYTES:
                    self.send_error(413)
                    return
                body = json.loads(self.rfile.read(length))
                with hook.changed:
                    hook.notifications.append(body)
                    hook.changed.notify_all()
                self.send_response(200)
                self.end_headers()

            def log_message(self, *args: Any) -> None:
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/"
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    def wait_for(self, predicate: Callable[[dict[str, Any]], bool], timeout_s: float, what: str) -> dict[str, Any]:
        """The first notification (old or new) that `predicate` accepts, waiting up to `timeout_s`."""
        deadline = time.monotonic() + timeout_s
        with self.changed:
            while True:
                found = next((n for n in self.notifications if predicate(n)), None)
                if found is not None:
                    return found
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"no {what} in {timeout_s:.0f} s; notifications: {self.notifications}")
                self.changed.wait(left)

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


def notified(alertname: str, status: str) -> Callable[[dict[str, Any]], bool]:
    """A notification that says `alertname` is `status` (firing or resolved)."""

    def match(n: dict[str, Any]) -> bool:
        return any(a["labels"].get("alertname") == alertname and a["status"] == status for a in n["alerts"])

    return match


@contextlib.contextmanager
def _serving(directory: pathlib.Path, name: str, config: dict[str, Any], *flags: str) -> Iterator[str]:
    """Debian's `name` with `config` (written to DIRECTORY/NAME.yml) on a free loopback port, until the end; yields
    its URL once it is ready. Its log: DIRECTORY/NAME.log."""
    path = directory / f"{name}.yml"
    path.write_text(yaml.safe_dump(config))
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    argv = [program(name), f"--config.file={path}", f"--web.listen-address=127.0.0.1:{port}", "--log.level=warn"]
    log = directory / f"{name}.log"
    with open(log, "wb") as out:
        proc = subprocess.Popen([*argv, *flags], stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    try:
        try:
            wait_http_ok(f"{url}/-/ready", proc, timeout_s=60)
        except RuntimeError as exc:
            raise RuntimeError(f"{exc}\n{log.read_text()[-2000:]}") from exc
        yield url
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@contextlib.contextmanager
def alertmanager(directory: pathlib.Path, webhook_url: str) -> Iterator[str]:
    """An Alertmanager that notifies `webhook_url` of every alert, firing and resolved, within about a second;
    yields its URL."""
    config = {
        "route": {
            "receiver": "test",
            "group_by": ["alertname"],
            "group_wait": "1s",
            "group_interval": "1s",
            "repeat_interval": "1h",
        },
        "receivers": [{"name": "test", "webhook_configs": [{"url": webhook_url, "send_resolved": True}]}],
    }
    storage = f"--storage.path={directory / 'alertmanager-data'}"
    # No gossip port (--cluster.listen-address empty): one Alertmanager, loopback only.
    with _serving(directory, "prometheus-alertmanager", config, storage, "--cluster.listen-address=") as url:
        yield url


class Prometheus:
    def __init__(self, url: str) -> None:
        self.url = url

    def query(self, expr: str) -> list[dict[str, Any]]:
        """An instant query's result (a vector's samples); AssertionError with Prometheus's error if it fails."""
        reply = requests.get(f"{self.url}/api/v1/query", params={"query": expr}, timeout=10).json()
        assert reply["status"] == "success", f"{expr}: {reply}"
        return reply["data"]["result"]

    def query_range(self, expr: str, start: float, end: float, step: float) -> list[dict[str, Any]]:
        params = {"query": expr, "start": start, "end": end, "step": step}
        reply = requests.get(f"{self.url}/api/v1/query_range", params=params, timeout=10).json()
        assert reply["status"] == "success", f"{expr}: {reply}"
        return reply["data"]["result"]

    def targets_up(self) -> dict[str, float]:
        return {r["metric"]["job"]: float(r["value"][1]) for r in self.query("up")}


@contextlib.contextmanager
def prometheus(
    directory: pathlib.Path,
    jobs: dict[str, list[tuple[str, dict[str, str]]]],
    rules: pathlib.Path | None = None,
    alertmanager_url: str | None = None,
    scrape: str = "2s",
) -> Iterator[Prometheus]:
    """A Prometheus scraping each job's (host:port, target labels) every `scrape` (also its timeout: a netapp busy
    on two shared cores may take a second to answer), evaluating `rules` every second and sending alerts to
    `alertmanager_url`."""
    config: dict[str, Any] = {
        "global": {"scrape_interval": scrape, "evaluation_interval": "1s", "scrape_timeout": scrape},
        "scrape_configs": [
            {"job_name": job, "static_configs": [{"targets": [t], "labels": labels} for t, labels in targets]}
            for job, targets in jobs.items()
        ],
    }
    if rules is not None:
        config["rule_files"] = [str(rules)]
    if alertmanager_url is not None:
        am = alertmanager_url.removeprefix("http://")
        config["alerting"] = {"alertmanagers": [{"static_configs": [{"targets": [am]}]}]}
    storage = f"--storage.tsdb.path={directory / 'prometheus-data'}"
    with _serving(directory, "prometheus", config, storage, "--rules.alert.resend-delay=1s") as url:
        yield Prometheus(url)
