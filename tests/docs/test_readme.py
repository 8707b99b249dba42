"""Every code block of README.md and docs/*.md runs as written.

Python, bash and sh blocks run in a scratch checkout (`.venv` linked, `../shared` beside it), unless the line
before a block is an HTML comment `<!-- readme-test: MODE -->`:

- `skip: REASON`: not run (a cluster, docker, or a server that runs until stopped); keep these few;
- `netapp`: a netapp serves YOLOX-Nano at a free port, written into the block where it says http://127.0.0.1:5896;
- `middleware`: a middleware (local backend, `robot-1`/`s3cret`) likewise where it says http://127.0.0.1:8080;
- `serve`: `netapp.server.serve()` is caught; the test serves the block's processor itself and sends it a frame;
- `brokers`: RabbitMQ, Mosquitto and librdkafka's mock Kafka run on free ports (tests/support/brokers.py), written
  into the block where it says amqp://127.0.0.1:5672, mqtt://127.0.0.1:1883 and kafka://127.0.0.1:9092.

A block that exports traces to http://127.0.0.1:4318 (Jaeger or a Collector, as docs/tracing.md has a user run)
exports them to the tests' own receiver there instead, which must get spans. No block imports the `tests` package:
a user who installs the package has none of it.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.support.paths import ROOT

README = ROOT / "README.md"
DOC_PAGES = [README, *sorted((ROOT / "docs").glob("*.md"))]
RUN_LANGS = {"python", "bash", "sh"}
NETAPP_URL = "http://127.0.0.1:5896"
MIDDLEWARE_URL = "http://127.0.0.1:8080"
OTLP_URL = "http://127.0.0.1:4318"  # Jaeger's or a Collector's OTLP/HTTP port
BROKER_URLS = ("amqp://127.0.0.1:5672", "mqtt://127.0.0.1:1883", "kafka://127.0.0.1:9092")


@dataclass(frozen=True)
class Block:
    page: str  # the page's path from the repository root
    line: int
    lang: str
    code: str
    mode: str  # "" (run as is), "skip", "netapp", "middleware", "serve"
    note: str = ""  # what the marker says after the mode


def readme_blocks(text: str, page: str = "README.md") -> list[Block]:
    """The fenced code blocks in the languages that run, with the mode of the marker before each."""
    blocks = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        match = re.match(r"^```(\w+)\s*$", lines[i])
        if not match:
            i += 1
            continue
        start = i
        end = next(j for j in range(i + 1, len(lines)) if lines[j].startswith("```"))
        before = next((lines[j] for j in range(start - 1, -1, -1) if lines[j].strip()), "")
        marker = re.match(r"^<!-- readme-test: (\w+):? ?(.*?) -->$", before.strip())
        mode, note = marker.groups() if marker else ("", "")
        if match.group(1) in RUN_LANGS:
            blocks.append(Block(page, start + 1, match.group(1), "\n".join(lines[start + 1 : end]) + "\n", mode, note))
        i = end + 1
    return blocks


BLOCKS = [block for path in DOC_PAGES for block in readme_blocks(path.read_text(), str(path.relative_to(ROOT)))]


def test_no_block_imports_the_tests_package():
    """What a user copies must run where the package is installed, without this repository's tests."""
    using = [f"{b.page}:{b.line}" for b in BLOCKS if re.search(r"^\s*(from|import) tests\b", b.code, re.MULTILINE)]
    assert using == []


def test_the_marker_list_stays_short():
    for path in DOC_PAGES:
        page = str(path.relative_to(ROOT))
        skipped = [f"{page}:{b.line} {b.note}" for b in BLOCKS if b.page == page and b.mode == "skip"]
        assert len(skipped) <= 3, skipped
    assert {b.mode for b in BLOCKS} <= {"", "skip", "netapp", "middleware", "serve", "brokers"}
    assert len({b.page for b in BLOCKS}) >= 5, "the docs pages' blocks are collected too"


@pytest.fixture
def checkout(tmp_path: Path, media_dir: Path, real_model_path: Path) -> Path:
    """A scratch folder standing for the checkout: `.venv` is this one's, `../shared` has the model and media."""
    shared = tmp_path / "shared"
    (shared / "models").mkdir(parents=True)
    (shared / "models" / "yolox_nano.onnx").symlink_to(real_model_path)
    (shared / "media").symlink_to(media_dir)
    work = tmp_path / "netapp-toolkit"
    work.mkdir()
    (work / ".venv").symlink_to(ROOT / ".venv")
    for part in ("tools", "tests"):  # blocks a developer runs from the root (tools.dashboards, tests.support.otlp)
        (work / part).symlink_to(ROOT / part)
    return work


def run_block(block: Block, cwd: Path, replace: dict[str, str]) -> subprocess.CompletedProcess:
    code = block.code
    for old, new in replace.items():
        code = code.replace(old, new)
    env = {**os.environ, "PATH": f"{ROOT / '.venv' / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}"}
    if block.lang == "python":
        argv = [sys.executable, "-c", code]
    else:
        argv = ["bash", "-euo", "pipefail", "-c", code]
    return subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=180)


@pytest.mark.parametrize("block", BLOCKS, ids=[f"{b.page}:{b.line}-{b.lang}" for b in BLOCKS])
def test_readme_block_runs(block: Block, request: pytest.FixtureRequest) -> None:
    if block.mode == "skip":
        pytest.skip(f"{block.page}:{block.line}: {block.note}")
    checkout = request.getfixturevalue("checkout")
    replace: dict[str, str] = {}
    if block.mode == "netapp":
        replace[NETAPP_URL] = request.getfixturevalue("real_netapp").url
    elif block.mode == "middleware":
        replace[MIDDLEWARE_URL] = request.getfixturevalue("local_middleware")
    elif block.mode == "brokers":
        replace.update(zip(BROKER_URLS, request.getfixturevalue("docs_brokers"), strict=True))
    elif block.mode == "serve":
        run_caught_serve(block, checkout, request)
        return
    receiver = None
    if OTLP_URL in block.code:
        from tests.support.otlp import OtlpReceiver

        receiver = OtlpReceiver().start()
        request.addfinalizer(receiver.stop)
        replace[OTLP_URL] = receiver.endpoint
    out = run_block(block, checkout, replace)
    assert out.returncode == 0, f"{block.page}:{block.line} failed:\n{out.stdout}\n{out.stderr}"
    if receiver is not None:
        assert receiver.wait_for(lambda spans: len(spans) >= 1), "the example's spans reached the receiver"
    if block.mode == "netapp" and "annotated" in block.code:
        assert list(checkout.glob("annotated.*")), "the example writes its annotated output"


def run_caught_serve(block: Block, checkout: Path, request: pytest.FixtureRequest) -> None:
    """Run the SDK example as written but with serve() caught; serve its processor here and send it dog.jpg."""
    import cv2

    import netapp.server
    from netapp.client import NetAppClient

    caught = []
    monkeypatch = request.getfixturevalue("monkeypatch")
    monkeypatch.setattr(netapp.server, "serve", lambda processor, **kwargs: caught.append(processor))
    monkeypatch.chdir(checkout)
    exec(compile(block.code, f"{block.page}:{block.line}", "exec"), {"__name__": "__main__"})  # as `python file.py`
    assert len(caught) == 1, "the example calls serve() once"
    exec(compile(block.code, f"{block.page}:{block.line}", "exec"), {"__name__": "mypackage.sharpness"})
    assert len(caught) == 1, "imported (netapp serve --processor), the example serves nothing itself"
    server = request.getfixturevalue("serve")(caught[0])
    frame = cv2.imread("../shared/media/dog.jpg")
    with NetAppClient(server.url, transport="http") as client:
        client.send(frame)
        result = next(client.results(timeout=10.0), None)
        assert result is not None, client.stats.last_error
    assert client.stats.errors == 0 and set(result.message) - {"detections"} > {"timestamp"}


@pytest.fixture
def real_netapp(serve, real_model_path):
    from netapp.models import Detector, DetectorConfig
    from netapp.serve_process import free_port
    from netapp.server.settings import Settings

    first = free_port()  # a few UDP ports: docs/cameras.md's `netapp stream --transport rtp`
    return serve(Detector(DetectorConfig(str(real_model_path))), Settings(lanes=1, rtp_ports=range(first, first + 4)))


@pytest.fixture(scope="module")
def docs_brokers() -> Iterator[tuple[str, str, str]]:
    """RabbitMQ, Mosquitto and librdkafka's mock Kafka (a test double, not Kafka) on free ports: their URLs."""
    from tests.support.brokers import KafkaMock, Mosquitto, RabbitMQ

    try:
        with RabbitMQ() as rabbit, Mosquitto() as mosquitto, KafkaMock() as kafka:
            yield f"amqp://127.0.0.1:{rabbit.port}", mosquitto.url, kafka.url.rstrip("/")
    except FileNotFoundError as exc:
        pytest.skip(str(exc))


@pytest.fixture
def local_middleware(tmp_path: Path, real_model_path: Path):
    """`netapp middleware` (local backend) as a process on a free port, with robot-1 / s3cret."""
    from netapp_middleware.auth import hash_secret

    from netapp.serve_process import free_port, wait_http_ok

    robots = tmp_path / "robots.yaml"
    robots.write_text(f"robots:\n  robot-1: '{hash_secret('s3cret', n=2**10)}'\n")
    port = free_port()
    argv = [sys.executable, "-m", "netapp", "middleware", "--robots-file", str(robots), "--model", str(real_model_path)]
    process = subprocess.Popen([*argv, "--port", str(port)], stderr=subprocess.PIPE, text=True)
    try:
        wait_http_ok(f"http://127.0.0.1:{port}/healthz", process, timeout_s=60)
        yield f"http://127.0.0.1:{port}"
    finally:
        process.terminate()
        process.wait(timeout=30)
