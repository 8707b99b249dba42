"""`netapp serve`: serve detection with an ONNX model."""

from __future__ import annotations

import argparse
import logging

from netapp.protocol import DEFAULT_PORT

log = logging.getLogger("netapp.serve")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--model", required=True, help="ONNX model: a path, or an http(s) URL (optionally #sha256=HEX)")
    parser.add_argument("--sha256", help="expected sha256 of the model file")
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (0.0.0.0 in a container)")
    parser.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"port (default {DEFAULT_PORT}, as 5G-ERA)")
    parser.add_argument("--labels", help="class names file, one per line (default: model metadata, else COCO)")
    parser.add_argument("--conf", type=float, default=0.3, help="score threshold (default 0.3)")
    parser.add_argument("--iou", type=float, default=0.45, help="NMS IoU threshold (default 0.45)")
    parser.add_argument("--max-payload", type=int, default=8 * 1024 * 1024, help="largest frame in bytes (8 MiB)")
    parser.add_argument("--queue-size", type=int, default=1, help="frames waiting per robot; newest wins (1)")
    parser.add_argument("--max-batch", type=int, default=0, help="frames per inference across robots (0: model's)")
    parser.add_argument("--threads", type=int, default=0, help="onnxruntime intra-op threads (0: all cores)")
    parser.add_argument(
        "--prepare-threads",
        type=int,
        default=None,
        help="decode threads beside inference (default: 0 on 2 cores or fewer, else 2)",
    )
    parser.add_argument("--download-timeout", type=float, default=60.0, help="model download timeout, seconds")


def run(args: argparse.Namespace) -> int:
    from netapp.detect import Detector, DetectorConfig
    from netapp.localproc import port_problem
    from netapp.server.model_source import ModelUnavailable, resolve_model
    from netapp.server.runner import run_server
    from netapp.server.settings import Settings

    problem = port_problem(args.host, args.port)
    if problem:  # before the model loads, so the answer comes at once
        log.error("%s", problem)
        return 2
    try:
        model_path = resolve_model(args.model, args.sha256, timeout_s=args.download_timeout)
        detector = Detector(DetectorConfig(str(model_path), args.labels, args.conf, args.iou, threads=args.threads))
        detector.load()  # fail at start-up with a clear message, not on the first frame
    except (ModelUnavailable, ValueError, OSError) as exc:
        log.error("%s", exc)
        return 2
    settings = Settings(max_payload_bytes=args.max_payload, queue_size=args.queue_size, max_batch=args.max_batch)
    if args.prepare_threads is not None:
        settings.prepare_threads = args.prepare_threads
    log.info("serving %s on http://%s:%d (provider %s)", model_path, args.host, args.port, detector.provider)
    run_server(detector, args.host, args.port, settings, log_level=args.log_level.lower())
    return 0
