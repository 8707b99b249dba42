"""The model flags of `netapp serve` (and of `netapp model inspect`, which shares the reading ones), and the
DetectorConfig they make: one definition for both commands. Light: argparse only at import."""

from __future__ import annotations

import argparse

from netapp.models.detector import DetectorConfig
from netapp.models.metadata import TASKS
from netapp.models.providers import DEVICES
from netapp.results import MASK_FORMATS


def add_reading_arguments(parser: argparse.ArgumentParser) -> None:
    """How the model is read: what its metadata and shapes say, unless these say otherwise."""
    parser.add_argument("--labels", help="class names file, one per line (default: model metadata, else COCO)")
    parser.add_argument(
        "--task", choices=TASKS, help="the model's task (default: its metadata's, else what its outputs look like)"
    )
    parser.add_argument(
        "--layout",
        metavar="FAMILY",
        help="read the outputs as this family's (yolox, yolov5, ultralytics, end2end, rtdetr, rfdetr, dfine; default:"
        " recognised from the model)",
    )


def add_model_arguments(parser: argparse.ArgumentParser) -> None:
    """`netapp serve`'s model flags."""
    detector = DetectorConfig(model_path="")
    add_reading_arguments(parser)
    parser.add_argument("--conf", type=float, default=detector.conf, help="score threshold (default %(default)s)")
    parser.add_argument("--iou", type=float, default=detector.iou, help="NMS IoU threshold (default %(default)s)")
    parser.add_argument(
        "--max-detections",
        type=int,
        default=detector.max_detections,
        help="detections per frame at most, best first (default %(default)s)",
    )
    parser.add_argument(
        "--mask-format",
        choices=MASK_FORMATS,
        default=detector.mask_format,
        help="instance masks as polygons (small) or COCO RLE (exact) (default %(default)s)",
    )
    parser.add_argument(
        "--device",
        choices=DEVICES,
        default=detector.device,
        help="where the model runs: auto takes the best onnxruntime offers, TensorRT > CUDA > OpenVINO > CPU "
        "(default %(default)s)",
    )
    parser.add_argument(
        "--trt-cache", metavar="DIR", help="TensorRT's engine cache, a volume (default ~/.cache/netapp/trt)"
    )
    parser.add_argument("--fp16", action="store_true", help="TensorRT and OpenVINO run in half precision")
    parser.add_argument(
        "--max-model-memory",
        type=int,
        metavar="MB",
        default=detector.max_model_memory_mb,
        help="memory the model's inference may take (onnxruntime's CPU arena, shared by the models of the process); "
        "a model that needs more is refused at start-up; 0: unbounded (default %(default)s)",
    )


def check_thresholds(conf: float, iou: float, max_detections: int) -> None:
    """ValueError, one line, for a threshold no model can use."""
    if not 0.0 <= conf < 1.0:
        raise ValueError(f"--conf {conf} is not a score threshold: give 0 <= conf < 1 (e.g. 0.25, or 0.0001)")
    if not 0.0 < iou <= 1.0:
        raise ValueError(f"--iou {iou} is not an overlap: give 0 < iou <= 1 (e.g. 0.7)")
    if max_detections < 1:
        raise ValueError(f"--max-detections {max_detections}: give 1 or more (e.g. 50)")


def detector_config(args: argparse.Namespace, model_path: str) -> DetectorConfig:
    """The DetectorConfig of `netapp serve`'s flags."""
    conf, iou = args.conf, args.iou
    max_detections = getattr(args, "max_detections", DetectorConfig.max_detections)
    check_thresholds(conf, iou, max_detections)
    return DetectorConfig(
        model_path,
        args.labels,
        conf,
        iou,
        max_detections=max_detections,
        device=getattr(args, "device", "auto"),
        trt_cache=getattr(args, "trt_cache", None),
        fp16=getattr(args, "fp16", False),
        threads=args.threads,
        spin_wait=getattr(args, "spin_wait", False),
        task=getattr(args, "task", None),
        layout=getattr(args, "layout", None),
        mask_format=getattr(args, "mask_format", "polygons"),
        max_pixels=getattr(args, "max_pixels", DetectorConfig.max_pixels),
        max_model_memory_mb=getattr(args, "max_model_memory", DetectorConfig.max_model_memory_mb),
    )
