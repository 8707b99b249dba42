#!/usr/bin/env python3
"""Screenshots of the netapp's pages for docs/server.md#live-pages, made the way a person would see them:

    python tools/screenshots.py [--model ../shared/models/yolox_nano.onnx] [--source ../shared/media/dog.jpg]

starts `netapp serve` on a free port, streams the source to it with `netapp stream` (two robots: ws and http),
opens /ui and the first robot's page in Debian's chromium (Playwright) and writes docs/ui-robots.png and
docs/ui-robot.png; then starts the middleware (local backend), has a robot deploy and stream through it, logs in
to /dashboard as an operator and writes docs/dashboard.png; then serves the test processor whose results carry
masks (polygons and RLE), keypoints, an oriented box and classes (tests/support/result_processors.py) and writes
docs/ui-masks.png (`--masks-only`: that one alone); then opens /camera in chromium with a fake camera playing the
shared video over WebRTC and writes docs/camera-webrtc.png (`--camera-only`: that one alone).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from netapp.serve_process import free_port, wait_http_ok

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared"


def netapp(*args: str) -> list[str]:
    return [sys.executable, "-m", "netapp", "--log-level", "WARNING", *args]


def shrink(path: Path) -> None:
    """256 colours (Pillow, which matplotlib brings with the bench extra): a photo's PNG shrinks about 4 times."""
    try:
        from PIL import Image
    except ImportError:
        return
    with Image.open(path) as image:
        small = image.convert("RGB").quantize(256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    small.save(path, optimize=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=str(SHARED / "models" / "yolox_nano.onnx"))
    parser.add_argument("--source", default=str(SHARED / "media" / "dog.jpg"))
    parser.add_argument("--out", default=str(ROOT / "docs"))
    parser.add_argument("--masks-only", action="store_true", help="write docs/ui-masks.png alone")
    parser.add_argument("--camera-only", action="store_true", help="write docs/camera-webrtc.png alone")
    parser.add_argument("--video", default=str(SHARED / "media" / "pedestrians.avi"), help="the /camera page's camera")
    args = parser.parse_args()
    chromium = shutil.which("chromium")
    if chromium is None:
        print("error: Debian's chromium is absent: apt-get install -y chromium", file=sys.stderr)
        return 2
    camera_page(args, chromium)
    if args.camera_only:
        print(f"wrote {args.out}/camera-webrtc.png")
        return 0
    masks_page(args, chromium)
    if args.masks_only:
        print(f"wrote {args.out}/ui-masks.png")
        return 0
    from playwright.sync_api import sync_playwright

    port = free_port()
    url = f"http://127.0.0.1:{port}"
    processes = [subprocess.Popen(netapp("serve", "--model", args.model, "--port", str(port)))]
    try:
        wait_http_ok(f"{url}/readyz", processes[0], 120)
        for robot, transport in (("robot-ws", "ws"), ("robot-http", "http")):
            stream = ["stream", url, "--source", args.source, "--transport", transport, "--robot-id", robot]
            processes.append(subprocess.Popen(netapp(*stream, "--duration", "60", "--json"), stdout=subprocess.DEVNULL))
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=chromium, args=["--no-sandbox"])
            page = browser.new_page(viewport={"width": 900, "height": 420})
            page.goto(f"{url}/ui")
            page.wait_for_function("document.querySelectorAll('#robots tbody tr').length >= 2", timeout=60_000)
            page.wait_for_timeout(3000)  # a few seconds of results for the rates and percentiles
            page.screenshot(path=str(Path(args.out) / "ui-robots.png"))
            page.set_viewport_size({"width": 760, "height": 1100})
            page.locator("#robots tbody tr", has_text="robot-ws").locator("a").click()
            page.wait_for_function("Number(document.body.dataset.frames) >= 30", timeout=60_000)
            page.screenshot(path=str(Path(args.out) / "ui-robot.png"), full_page=True)
            browser.close()
    finally:
        for process in reversed(processes):
            process.terminate()
            process.wait(timeout=30)
    dashboard(args, chromium)
    for name in ("ui-robots.png", "ui-robot.png", "dashboard.png"):
        shrink(Path(args.out) / name)
    print(f"wrote {args.out}/ui-robots.png, ui-robot.png and dashboard.png")
    return 0


def masks_page(args: argparse.Namespace, chromium: str) -> None:
    """A robot's page with masks, keypoints, an oriented box and classes drawn (a test processor's, on a grey
    frame: no model with trained segmentation or pose weights is at hand)."""
    import cv2
    import numpy as np
    from playwright.sync_api import sync_playwright

    port = free_port()
    url = f"http://127.0.0.1:{port}"
    serve = ["serve", "--processor", "tests.support.result_processors:SceneProcessor", "--port", str(port)]
    processes = [subprocess.Popen(netapp(*serve), cwd=ROOT)]
    with tempfile.TemporaryDirectory() as tmp:
        frame = Path(tmp) / "grey.png"
        cv2.imwrite(str(frame), np.full((480, 640, 3), 90, np.uint8))
        try:
            wait_http_ok(f"{url}/readyz", processes[0], 60)
            stream = ["stream", url, "--source", str(frame), "--robot-id", "mask-bot", "--duration", "60", "--json"]
            processes.append(subprocess.Popen(netapp(*stream), stdout=subprocess.DEVNULL))
            with sync_playwright() as playwright:
                browser = playwright.chromium.launch(executable_path=chromium, args=["--no-sandbox"])
                page = browser.new_page(viewport={"width": 760, "height": 900})
                page.goto(f"{url}/ui")
                page.locator("#robots tbody tr", has_text="mask-bot").locator("a").click()
                page.wait_for_function("Number(document.body.dataset.frames) >= 20", timeout=60_000)
                page.screenshot(path=str(Path(args.out) / "ui-masks.png"), full_page=True)
                browser.close()
        finally:
            for process in reversed(processes):
                process.terminate()
                process.wait(timeout=30)
    shrink(Path(args.out) / "ui-masks.png")


def camera_page(args: argparse.Namespace, chromium: str) -> None:
    """/camera with chromium's fake camera playing the shared video: its WebRTC track to the netapp, boxes drawn."""
    from playwright.sync_api import sync_playwright

    from tests.support.fake_camera import camera_flags, fake_camera

    port = free_port()
    url = f"http://127.0.0.1:{port}"
    processes = [subprocess.Popen(netapp("serve", "--model", args.model, "--port", str(port)))]
    with tempfile.TemporaryDirectory() as tmp:
        camera = fake_camera(Path(args.video), Path(tmp) / "camera.y4m", seconds=4, size="960:540")
        try:
            wait_http_ok(f"{url}/readyz", processes[0], 120)
            with sync_playwright() as playwright:
                flags = ["--no-sandbox", *camera_flags(camera)]
                browser = playwright.chromium.launch(executable_path=chromium, args=flags)
                page = browser.new_page(viewport={"width": 1000, "height": 760})
                page.goto(f"{url}/camera")
                page.click("#start")
                page.wait_for_function("Number(document.body.dataset.results) >= 30", timeout=60_000)
                page.screenshot(path=str(Path(args.out) / "camera-webrtc.png"))
                browser.close()
        finally:
            for process in reversed(processes):
                process.terminate()
                process.wait(timeout=30)
    shrink(Path(args.out) / "camera-webrtc.png")


def dashboard(args: argparse.Namespace, chromium: str) -> None:
    from netapp_middleware.auth import hash_secret
    from playwright.sync_api import sync_playwright

    port = free_port()
    url = f"http://127.0.0.1:{port}"
    with tempfile.TemporaryDirectory() as tmp:
        robots, operators = Path(tmp) / "robots.yaml", Path(tmp) / "operators.yaml"
        robots.write_text(f"robot-1: '{hash_secret('robot-secret')}'\n")
        operators.write_text(f"ada: '{hash_secret('operator-secret')}'\n")
        middleware = ["middleware", "--robots-file", str(robots), "--operators-file", str(operators)]
        processes = [subprocess.Popen(netapp(*middleware, "--model", args.model, "--port", str(port)))]
        try:
            wait_http_ok(f"{url}/healthz", processes[0], 60)
            robot = ["stream", "--middleware", url, "--robot-id", "robot-1", "--secret", "robot-secret"]
            robot += ["--source", args.source, "--duration", "60", "--json"]
            processes.append(subprocess.Popen(netapp(*robot), stdout=subprocess.DEVNULL))
            with sync_playwright() as playwright:
                browser = playwright.chromium.launch(executable_path=chromium, args=["--no-sandbox"])
                page = browser.new_page(viewport={"width": 1100, "height": 420})
                page.goto(f"{url}/dashboard")
                page.fill("input[name=operator]", "ada")
                page.fill("input[name=secret]", "operator-secret")
                page.click("button[type=submit]")
                page.locator("#netapps tbody tr", has_text="Ready").wait_for(timeout=120_000)
                page.screenshot(path=str(Path(args.out) / "dashboard.png"))
                browser.close()
        finally:
            for process in reversed(processes):
                process.terminate()
                process.wait(timeout=30)


if __name__ == "__main__":
    sys.exit(main())
