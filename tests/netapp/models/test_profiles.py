"""A netapp names an accuracy profile only when it was made for its own model (the profile records the model file's
sha256); with none, /register and INIT's session_info say None, and robots adapt on their conservative defaults."""

from __future__ import annotations

import json

import requests

from netapp.models import Detector, DetectorConfig
from netapp.models.profiles import SHA256_FIELD, profile_for, profiles_by_model
from netapp.models.source import sha256_of
from tests.support.exports import export_path
from tests.support.raw_robot import RawRobot


def test_the_shipped_profile_records_its_model(real_model_path):
    assert profile_for(real_model_path) == "yolox_nano"
    assert profiles_by_model()[sha256_of(real_model_path)] == "yolox_nano"


def test_a_profile_is_found_by_the_model_file_not_its_name(tmp_path, real_model_path):
    copy = tmp_path / "renamed.onnx"
    copy.write_bytes(real_model_path.read_bytes())
    assert profile_for(copy) == "yolox_nano"
    (tmp_path / "other.json").write_text(json.dumps({SHA256_FIELD: "0" * 64}))
    (tmp_path / "broken.json").write_text("{not json")
    assert profiles_by_model(tmp_path) == {"0" * 64: "other"}
    assert profile_for(copy, tmp_path) is None


def test_register_and_init_name_the_profile_only_for_its_model(serve, real_model_path, tiny_model_path):
    for path, expected in ((real_model_path, "yolox_nano"), (tiny_model_path, None), (export_path("yolo11n"), None)):
        detector = Detector(DetectorConfig(str(path)))
        server = serve(detector)
        answer = requests.post(f"{server.url}/register", json={}, timeout=5).json()
        assert answer["accuracy_profile"] == expected
        robot = RawRobot(server.url)
        try:
            assert tuple(robot.init()) == (True, "initialized")
            assert robot.next("session_info")["accuracy_profile"] == expected
        finally:
            robot.close()
