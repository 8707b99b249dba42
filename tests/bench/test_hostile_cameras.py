"""bench/hostile.py's attacks of issue 45, small: each runs against a real `netapp serve` process and reports what
the netapp counted (the full-size run is `python -m bench.hostile`)."""

from __future__ import annotations

import pytest

from bench.hostile import Target
from bench.hostile_cameras import (
    FailingCameras,
    camera_bad_urls,
    camera_secrets,
    rtp_sequence_jumps,
    watch_hold,
    webrtc_candidates,
    webrtc_never_connect,
)


@pytest.fixture(scope="module")
def target(tiny_model_path, tmp_path_factory):
    cameras = FailingCameras()
    t = Target(str(tiny_model_path), tmp_path_factory.mktemp("hostile") / "netapp.log", cameras)
    yield t
    t.close()
    cameras.close()


def test_the_cameras_passwords_are_in_no_output_and_bad_urls_exit_2(target):
    tried, lost, note = camera_secrets(target)
    assert (tried, lost) == (8, 0) and note.endswith("secrets: 0"), note
    assert target.log_path.read_text().count("S3cr3tPw1") == 0
    tried, lost, note = camera_bad_urls(target)
    assert lost == 0 and note.endswith("secrets: 0"), note


def test_webrtc_rtp_and_watch_attacks_are_refused_and_counted(target):
    pytest.importorskip("aiortc", reason="aiortc is not installed: pip install 'netapp-toolkit[webrtc]'")
    _, lost, note = webrtc_never_connect(target, rounds=1)
    assert lost == 0 and "7 bad_sdp counted; 0 peers held" in note, note
    _, _, note = webrtc_candidates(target, offers=1, each=10)
    assert "10 of 10 candidates dropped" in note, note
    _, _, note = rtp_sequence_jumps(target, seconds=1.0, rate=500)
    restarts = int(note.split("; ")[1].split()[0])
    assert restarts >= 100, note
    _, refused, note = watch_hold(target, held=6, real=2)
    assert refused == 0 and "'too_many_watchers': 2" in note and "'ok': 4" in note, note
