"""Models from a path or a URL: cached download, checksum, timeout, clear errors."""

from __future__ import annotations

import hashlib
import http.server
import threading

import pytest

from netapp.models.source import ModelUnavailable, resolve_model


@pytest.fixture
def file_server(tmp_path):
    (tmp_path / "model.onnx").write_bytes(b"model-bytes")
    handler = lambda *a, **kw: http.server.SimpleHTTPRequestHandler(*a, directory=str(tmp_path), **kw)  # noqa: E731
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    httpd.requests = 0
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield httpd
    httpd.shutdown()


def test_download_once_into_the_cache_and_verify_sha256(tmp_path, file_server):
    url = f"http://127.0.0.1:{file_server.server_port}/model.onnx"
    digest = hashlib.sha256(b"model-bytes").hexdigest()
    cache = tmp_path / "cache"
    path = resolve_model(f"{url}#sha256={digest}", cache_dir=cache)
    assert path.read_bytes() == b"model-bytes" and path.parent == cache
    (tmp_path / "model.onnx").unlink()  # a second resolve must come from the cache
    assert resolve_model(url, sha256=digest, cache_dir=cache) == path


def test_checksum_mismatch_and_missing_files_are_clear(tmp_path, file_server):
    url = f"http://127.0.0.1:{file_server.server_port}/model.onnx"
    with pytest.raises(ModelUnavailable, match="does not match sha256"):
        resolve_model(url, sha256="0" * 64, cache_dir=tmp_path / "c")
    assert not list((tmp_path / "c").glob("*.part"))  # no half file left behind
    with pytest.raises(ModelUnavailable, match="cannot download.*404"):
        resolve_model(f"http://127.0.0.1:{file_server.server_port}/absent.onnx", cache_dir=tmp_path / "c")
    with pytest.raises(ModelUnavailable, match="does not exist"):
        resolve_model(str(tmp_path / "absent.onnx"))
    local = tmp_path / "model.onnx"
    with pytest.raises(ModelUnavailable, match="does not match"):
        resolve_model(str(local), sha256="f" * 64)


def test_a_stalled_download_times_out(tmp_path):
    import socket

    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)  # accepts the connection, never answers
    try:
        with pytest.raises(ModelUnavailable, match="cannot download"):
            resolve_model(f"http://127.0.0.1:{listener.getsockname()[1]}/m.onnx", cache_dir=tmp_path, timeout_s=1)
    finally:
        listener.close()
