"""The cameras' pure parts: naming a camera, the reconnect backoff, telling an outage once, keeping up."""

from __future__ import annotations

import re

import pytest

from netapp.backoff import CAP_S, FIRST_S, Outage, backoff_s
from netapp.server.sources.keeping_up import MAX_BEHIND_S, KeepingUp
from netapp.server.sources.naming import MAX_SOURCES, open_options, parse_source, parse_sources
from netapp.server.sources.redaction import redact, redact_camera


def test_backoff_doubles_up_to_its_cap_with_half_of_each_step_random():
    low = [backoff_s(n, rand=lambda: 0.0) for n in range(8)]
    high = [backoff_s(n, rand=lambda: 0.999999) for n in range(8)]
    assert low[0] == pytest.approx(FIRST_S / 2) and high[0] == pytest.approx(FIRST_S, rel=1e-5)
    assert low[1] == pytest.approx(FIRST_S) and low[2] == pytest.approx(2 * FIRST_S)
    assert max(high) == pytest.approx(CAP_S, rel=1e-5) and low[-1] == pytest.approx(CAP_S / 2)
    assert all(a <= b for a, b in zip(low, low[1:], strict=False))
    assert backoff_s(10_000) <= CAP_S and backoff_s(-3) >= FIRST_S / 2  # no overflow, no negative exponent


def test_backoff_jitter_spreads_cameras_lost_together():
    waits = {round(backoff_s(6), 6) for _ in range(50)}
    assert len(waits) > 40 and all(CAP_S / 2 <= w <= CAP_S for w in waits)


def test_an_outage_is_told_once_when_lost_and_once_when_back_with_its_length():
    outage = Outage("cam")
    assert outage.connected(0.0) == "camera cam: connected"
    assert outage.connected(1.0) is None  # still up: nothing to say
    lines = [outage.failed(10.0, "Connection refused")] + [
        outage.failed(10.0 + n, "Connection refused") for n in range(1, 20)
    ]
    assert lines[0] == ("camera cam: lost (Connection refused); retrying quietly (every 1 s at most) till it is back")
    assert lines[1:] == [None] * 19 and outage.attempts == 20 and outage.outages == 1
    assert outage.connected(22.5) == "camera cam: back after 12.5 s"
    assert outage.attempts == 0
    assert outage.failed(30.0, "timeout") is not None and outage.outages == 2  # the next outage is told again


def test_a_camera_never_reached_is_unreachable_then_connected():
    outage = Outage("cam")
    assert "unreachable" in outage.failed(0.0, "Connection refused")
    assert outage.failed(1.0, "Connection refused") is None
    assert outage.connected(3.0) == "camera cam: connected after 3.0 s" and outage.outages == 0


def test_keeping_up_measures_lag_against_the_best_offset_seen():
    keeping = KeepingUp()
    assert keeping.behind_s(100.0, 0.0) == 0.0
    assert keeping.behind_s(100.5, 0.5) == pytest.approx(0.0)  # in step with the camera
    assert keeping.behind_s(101.6, 1.0) == pytest.approx(0.6)  # decoded 0.6 s late
    assert not keeping.cannot_keep_up(101.0 + MAX_BEHIND_S, 1.0)
    assert keeping.cannot_keep_up(101.5 + MAX_BEHIND_S, 1.0)
    assert keeping.behind_s(200.0, None) == 0.0  # a picture without a time says nothing
    assert keeping.behind_s(300.0, 0.2) == 0.0  # the clock went back (a restarted camera): a new baseline


def test_a_source_is_a_name_and_an_rtsp_url_with_our_transport_after_the_hash():
    spec = parse_source("door=rtsp://admin:secret@10.0.0.5:554/stream1?channel=1#transport=tcp")
    assert (spec.name, spec.transport) == ("door", "tcp")
    assert spec.url == "rtsp://admin:secret@10.0.0.5:554/stream1?channel=1"  # the fragment never reaches the camera
    assert spec.shown_url == "rtsp://10.0.0.5:554/stream1?channel=1"  # no credentials in logs
    assert open_options(spec)["rtsp_transport"] == "tcp"
    auto = parse_source("yard=rtsps://cam.example/live")
    assert auto.transport == "auto" and "rtsp_transport" not in open_options(auto)
    assert {"fflags": "nobuffer", "timeout": "3000000"}.items() <= open_options(auto).items()
    old = open_options(auto, libavformat_major=58)  # FFmpeg 4: `timeout` would make it listen as a server
    assert old["stimeout"] == "3000000" and "timeout" not in old


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("rtsp://cam/x", "NAME=rtsp://"),
        ("door=", "NAME=rtsp://"),
        ("bad name=rtsp://cam/x", "letters, digits"),
        ("door=http://cam/x", "rtsp:// or rtsps://"),
        ("door=rtsp:///x", "with a host"),
        ("door=rtsp://cam/x#transport=sctp", "udp, tcp"),
        ("door=rtsp://cam/x#fps=5", "unknown option"),
        ("door=rtsp://cam/" + "x" * 3000, "over 2048"),
    ],
)
def test_a_bad_source_is_one_line_saying_what_to_write(text, says):
    with pytest.raises(ValueError, match=says.replace("/", "/").replace(".", r"\.").replace("?", r"\?")) as info:
        parse_source(text)
    assert "\n" not in str(info.value)


def test_sources_are_unique_and_bounded():
    with pytest.raises(ValueError, match="door given twice"):
        parse_sources(["door=rtsp://a/x", "door=rtsp://b/x"])
    with pytest.raises(ValueError, match=f"at most {MAX_SOURCES}"):
        parse_sources([f"c{n}=rtsp://a/{n}" for n in range(MAX_SOURCES + 1)])
    assert [s.name for s in parse_sources(["a=rtsp://h/1", "b=rtsp://h/2"])] == ["a", "b"]


SECRET = "S3cr3tPw1"


@pytest.mark.parametrize(
    ("url", "says"),
    [
        (f"rtsp://admin:{SECRET}/x@10.0.0.5/cam", "'/', '?' or '#' in the password"),
        (f"rtsp://admin:{SECRET}?x@10.0.0.5/cam", "'/', '?' or '#' in the password"),
        (f"rtsp://admin:{SECRET}#x@10.0.0.5/cam", "'/', '?' or '#' in the password"),
        (f"rtsp://admin:{SECRET}@x@10.0.0.5/cam", "two '@'"),
        (f"rtsp://admin:{SECRET} x@10.0.0.5/cam", "a space"),
        (f"rtsp://admin:{SECRET}\x00@10.0.0.5/cam", "a control"),
        (f"rtsp://admin:{SECRET}%zz@10.0.0.5/cam", "cannot carry as is"),
        (f"rtsp://admin:{SECRET}@10.0.0.5:99999/cam", "from 1 to 65535"),
        (f"rtsp://admin:{SECRET}@10.0.0.5:0/cam", "from 1 to 65535"),
        (f"rtsp://admin:{SECRET}@10.0.0.5:55x/cam", "from 1 to 65535"),
        (f"rtsp://admin:{SECRET}@cam_era/cam", "as its host"),
        (f"rtsp://admin:{SECRET}@[::1/cam", "as its host"),
        (f"rtsp://admin:{SECRET}@10.0.0.5/c<a>m", "path holds"),
        (f"rtsp://admin:{SECRET}@10.0.0.5/cam#transport", "udp, tcp"),
        (f"http://admin:{SECRET}@10.0.0.5/cam", "rtsp:// or rtsps://"),
    ],
)
def test_a_url_ffmpeg_would_read_otherwise_is_refused_at_start_without_its_password(url, says):
    with pytest.raises(ValueError, match=re.escape(says)) as info:
        parse_source(f"door={url}")
    assert SECRET not in str(info.value) and "\n" not in str(info.value)


def test_escaped_passwords_ipv6_hosts_and_ports_are_taken_as_written():
    spec = parse_source("door=rtsp://admin:p%40ss%2Fw%3F@[fe80::1]:8554/cam?ch=1#transport=udp")
    assert spec.url == "rtsp://admin:p%40ss%2Fw%3F@[fe80::1]:8554/cam?ch=1" and spec.transport == "udp"
    assert spec.shown_url == "rtsp://[fe80::1]:8554/cam?ch=1"
    assert parse_source("door=rtsps://cam.example.:322/").url == "rtsps://cam.example.:322/"


def test_ffmpegs_errors_lose_the_credentials_in_every_form():
    spec = parse_source("door=rtsp://admin:p%40ss%2Fw0rd@10.0.0.5:554/cam")
    texts = [
        f"Server returned 401 Unauthorized (authorization failed): '{spec.url}'",
        "Connection refused: 'rtsp://admin:p@ss/w0rd@10.0.0.5:554/cam'",  # decoded, as a log might show it
        "auth failed for admin:p%40ss%2Fw0rd, p@ss/w0rd, p%40ss%2Fw0rd",
        "Location: rtsp://other:hunter2@10.0.0.6/cam",  # any URL's credentials, a redirect's too
    ]
    for text in texts:
        shown = redact_camera(text, spec.url)
        assert "p%40ss" not in shown and "p@ss" not in shown and "hunter2" not in shown, shown
    assert redact_camera(texts[0], spec.url).endswith("'rtsp://***@10.0.0.5:554/cam'")
    assert redact("rtsp://10.0.0.5/cam has no user") == "rtsp://10.0.0.5/cam has no user"


def test_a_reader_never_started_is_stopped_and_joined_without_a_traceback():
    from prometheus_client import CollectorRegistry

    from netapp.server.sources.metrics import SourceMetrics
    from netapp.server.sources.reader import CameraReader

    metrics = SourceMetrics(CollectorRegistry())
    reader = CameraReader(parse_source("door=rtsp://cam/x"), lambda *a: None, metrics, 640 * 480, 1 << 20)
    reader.stop()
    assert reader.join(0.1) and not reader.alive  # before: "cannot join thread before it is started" at Ctrl-C


def test_a_pause_of_the_camera_is_no_decoding_backlog_and_ffmpeg_errors_are_words():
    from netapp.server.sources.keeping_up import KeepingUp
    from netapp.server.sources.reader import describe

    keeping = KeepingUp()
    assert not keeping.cannot_keep_up(10.0, 1.0)
    keeping.restart()  # the camera paused 3 s and its clock did not move on
    assert not keeping.cannot_keep_up(13.1, 1.1) and not keeping.cannot_keep_up(13.2, 1.2)
    av = pytest.importorskip("av")
    error = av.error.ExitError(-1414092869, "Immediate exit requested", "rtsp://user:secret@10.0.0.9/cam")
    assert describe(error, parse_source("cam=rtsp://user:secret@10.0.0.9/cam")) == "Immediate exit requested"
