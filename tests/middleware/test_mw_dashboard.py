"""The middleware's dashboard in a real headless browser: an operator logs in (robots' credentials and tokens do
not work there), sees the NetApp a robot deployed (phase, URL linking to its live page, robots) and the robot's
deployment, and sees it go when the robot leaves."""

from __future__ import annotations

import subprocess
import sys

import requests
from netapp_middleware.auth import hash_secret

from netapp.client.middleware import MiddlewareClient
from netapp.serve_process import free_port, wait_http_ok
from tests.support.polling import wait_until


def test_an_operator_sees_the_netapps_and_the_robots_live(tmp_path, tiny_model_path, chromium):
    robots, operators = tmp_path / "robots.yaml", tmp_path / "operators.yaml"
    robots.write_text(f"robots:\n  robot-1: '{hash_secret('robot-secret', n=2**10)}'\n")
    operators.write_text(f"ada: '{hash_secret('operator-secret', n=2**10)}'\n")
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    argv = [sys.executable, "-m", "netapp", "middleware", "--robots-file", str(robots), "--operators-file"]
    middleware = subprocess.Popen(
        [*argv, str(operators), "--model", str(tiny_model_path), "--port", str(port)], stderr=subprocess.DEVNULL
    )
    page = chromium.new_page()
    try:
        wait_http_ok(f"{url}/healthz", middleware, timeout_s=60)
        robot = MiddlewareClient(url, "robot-1", "robot-secret")
        endpoint = robot.deploy("object-detection", placement="edge", timeout=120)

        assert requests.get(f"{url}/dashboard/api/state", timeout=5).status_code == 401
        bearer = {"Authorization": f"Bearer {robot._token}"}
        assert requests.get(f"{url}/dashboard/api/state", headers=bearer, timeout=5).status_code == 401
        as_robot = {"operator": "robot-1", "secret": "robot-secret"}
        assert requests.post(f"{url}/dashboard/login", json=as_robot, timeout=5).status_code == 401

        page.goto(f"{url}/dashboard")
        page.locator("#login").wait_for(timeout=15_000)
        page.fill("input[name=operator]", "ada")
        page.fill("input[name=secret]", "operator-secret")
        page.click("button[type=submit]")
        row = page.locator("#netapps tbody tr", has_text="object-detection")
        row.wait_for(timeout=15_000)
        cells = row.locator("td").all_inner_texts()
        assert cells[2] == "Ready" and cells[4] == endpoint.url and cells[5] == "robot-1"
        assert row.locator("a").get_attribute("href") == f"{endpoint.url}/ui"  # the netapp's own live page
        deployment = page.locator("#robots tbody tr", has_text="robot-1")
        assert "object-detection" in deployment.inner_text()
        assert page.locator("#operator").inner_text() == "ada"

        robot.close()  # deletes its deployment: the page follows by itself
        page.wait_for_function("document.querySelectorAll('#netapps tbody tr').length === 0", timeout=30_000)
        page.click("#logout")
        page.locator("#login").wait_for(timeout=10_000)
    finally:
        page.close()
        middleware.terminate()
        middleware.wait(timeout=30)
    wait_until(lambda: middleware.returncode is not None, what="the middleware to stop")
