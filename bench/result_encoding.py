"""How results are encoded: JSON (stdlib, ujson, orjson: the one the data path uses) against a packed binary layout.

    flock /tmp/heavy.lock python -m bench.result_encoding --detections 8

A YOLOX result message (the netapp's four stamps, `detections` with class id, name, score and box) is encoded on
the netapp and decoded on the robot, `--count` times; prints µs per result for each encoding and its size. The
binary layout is the least a result needs: a fixed header, then per detection its class id, score and box as
float32, with class names sent apart (once) as a real protocol would.
"""

from __future__ import annotations

import argparse
import json
import struct
import time

import ujson

from netapp import wire_json

HEAD = struct.Struct("<qqqqqI")  # timestamp, the four stamps, detection count
DETECTION = struct.Struct("<Hf4f")  # class id, score, box


def result(detections: int) -> dict:
    return {
        "timestamp": 1732492800123456789,
        "recv_timestamp": 1732492800124456789,
        "timestamp_before_process": 1732492800125456789,
        "timestamp_after_process": 1732492800141456789,
        "send_timestamp": 1732492800142456789,
        "dropped": 0,
        "detections": [
            {"class_id": 0, "class_name": "person", "score": 0.8123, "bbox": [12.5 + i, 40.25, 88.0, 190.75]}
            for i in range(detections)
        ],
    }


def pack(message: dict) -> bytes:
    detections = message["detections"]
    head = HEAD.pack(
        message["timestamp"],
        message["recv_timestamp"],
        message["timestamp_before_process"],
        message["timestamp_after_process"],
        message["send_timestamp"],
        len(detections),
    )
    return head + b"".join(DETECTION.pack(d["class_id"], d["score"], *d["bbox"]) for d in detections)


def unpack(data: bytes, names: list[str]) -> dict:
    stamps = HEAD.unpack_from(data)
    detections = []
    for i in range(stamps[5]):
        class_id, score, *box = DETECTION.unpack_from(data, HEAD.size + i * DETECTION.size)
        detections.append({"class_id": class_id, "class_name": names[class_id], "score": score, "bbox": box})
    keys = ("timestamp", "recv_timestamp", "timestamp_before_process", "timestamp_after_process", "send_timestamp")
    return {**dict(zip(keys, stamps[:5], strict=True)), "detections": detections}


ENCODINGS = {
    "JSON (stdlib)": (lambda m: json.dumps({"event": "results", "data": m}), json.loads),
    "JSON (ujson)": (lambda m: ujson.dumps({"event": "results", "data": m}), ujson.loads),
    "JSON (orjson: netapp.wire_json)": (lambda m: wire_json.dumps({"event": "results", "data": m}), wire_json.loads),
    "binary (struct)": (pack, lambda d: unpack(d, ["person"])),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--detections", type=int, default=8)
    parser.add_argument("--count", type=int, default=20000)
    args = parser.parse_args()
    message = result(args.detections)
    print(f"| encoding | encode (µs) | decode (µs) | bytes |  ({args.detections} detections)")
    print("|---|---:|---:|---:|")
    for name, (encode, decode) in ENCODINGS.items():
        data = encode(message)
        t0 = time.perf_counter()
        for _ in range(args.count):
            encode(message)
        t1 = time.perf_counter()
        for _ in range(args.count):
            decode(data)
        t2 = time.perf_counter()
        print(f"| {name} | {(t1 - t0) / args.count * 1e6:.1f} | {(t2 - t1) / args.count * 1e6:.1f} | {len(data)} |")


if __name__ == "__main__":
    main()
