"""Object detection with onnxruntime: YOLOX, YOLOv5 and YOLOv8/YOLO11 ONNX exports."""

from netapp.models.detector import Detector, DetectorConfig

__all__ = ["Detector", "DetectorConfig"]
