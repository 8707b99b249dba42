"""The broker message (netapp/broker/message.py) against its documented schema (docs/broker/result.schema.json) and
AsyncAPI document: every field a result may carry, and what the schema refuses."""

from __future__ import annotations

import jsonschema
import pytest
import yaml

from netapp.broker.address import DEFAULT_ADDRESSING
from netapp.broker.message import SCHEMA, ModelIdentity, encode, result_message
from netapp.results import Classification, Detection, Mask, to_wire
from tests.support.broker_schema import ASYNCAPI_PATH, SCHEMA_PATH, checked, validator

SHA = "ab" * 32


def a_result(**extra) -> dict:
    return {
        "timestamp": 1_700_000_000_000_000_000,
        "recv_timestamp": 5_000_000,
        "timestamp_before_process": 6_000_000,
        "timestamp_after_process": 9_000_000,
        "send_timestamp": 9_500_000,
        "detections": [],
        "dropped": 0,
        "hint": {"input_size": [416, 416]},
        **extra,
    }


def test_a_plain_result_is_wrapped_with_source_netapp_model_capture_time_and_latency():
    message = result_message(
        a_result(), netapp="edge", source="robot-1", session_id="s1", model=ModelIdentity("yolox_nano", SHA)
    )
    assert checked(encode(message)) == message
    assert message["schema"] == SCHEMA and message["id"] == "edge/s1/1700000000000000000"
    assert message["capture_ns"] == 1_700_000_000_000_000_000 and message["latency_ms"] == pytest.approx(4.5)
    assert message["model"] == {"name": "yolox_nano", "sha256": SHA} and message["source"] == "robot-1"


def test_masks_keypoints_rboxes_classes_and_track_ids_are_valid():
    import numpy as np

    square = np.zeros((40, 40), dtype=bool)
    square[10:30, 10:30] = True
    detections = to_wire(
        [
            Detection([1, 2, 30, 40], 0.9, 0, "person", mask=Mask.from_array(square), keypoints=[[1.0, 2.0, 0.9]] * 17),
            Detection([5, 5, 9, 9], 0.5, 16, "dog", mask=Mask.from_array(square, fmt="rle"), rbox=[7, 7, 4, 4, 0.3]),
        ]
    )
    detections[0]["track_id"] = 12
    result = a_result(detections=detections, classifications=to_wire([Classification(207, "golden retriever", 0.8)]))
    body = encode(result_message(result, netapp="n", source="cam", session_id="s", model=ModelIdentity("m")))
    message = checked(body)
    assert message["result"]["detections"][0]["track_id"] == 12 and message["model"]["sha256"] is None


@pytest.mark.parametrize(
    "spoil",
    [
        lambda m: m.pop("source"),
        lambda m: m.update(extra=1),
        lambda m: m["model"].update(sha256="xyz"),
        lambda m: m["result"]["detections"].append({"bbox": [1, 2, 3], "score": 1, "class": 0, "class_name": "a"}),
        lambda m: m["result"].update(detections=[{"bbox": [1, 2, 3, 4], "score": 1, "class": 0}]),
    ],
)
def test_the_schema_refuses_what_a_reader_could_not_rely_on(spoil):
    message = result_message(a_result(), netapp="n", source="r", session_id="s", model=ModelIdentity("m", SHA))
    spoil(message)
    with pytest.raises(jsonschema.ValidationError):
        validator().validate(message)


def test_the_asyncapi_document_names_every_default_address_and_the_schema():
    document = yaml.safe_load(ASYNCAPI_PATH.read_text())
    assert document["asyncapi"].startswith("3.")
    addresses = {c["address"] for c in document["channels"].values()}
    routes = ("routing_key", "topic", "available")
    defaults = {v for kind in DEFAULT_ADDRESSING.values() for name, v in kind.items() if name in routes}
    assert addresses == defaults and defaults >= {"results.{netapp}.{source}", "netapp/{netapp}/available"}
    payload = document["components"]["messages"]["result"]["payload"]["schema"]["$ref"]
    assert (ASYNCAPI_PATH.parent / payload).resolve() == SCHEMA_PATH.resolve()
    assert document["operations"]["publishMqtt"]["bindings"]["mqtt"]["qos"] == 1
