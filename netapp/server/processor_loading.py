"""Which processor `netapp serve --processor` runs: a built-in name, or any `package.module:Class`.

Built-in processors are chosen by name from `netapp.builtin_processors.BUILTIN` (add one there to offer it by name);
they take the detector's options (--model, --labels, --conf, --iou, --threads). A `module:Class` is imported, must
subclass `netapp.sdk.Processor`, and is made with no arguments (it loads its own weights in `load()`, which the
netapp calls once at start-up; /readyz answers 200 after it).
"""

from __future__ import annotations

import argparse
import importlib

from netapp.sdk.processor import Processor


class ProcessorUnavailable(Exception):
    """The processor cannot be had; the message says why and what to do."""


def _built_in(name: str, args: argparse.Namespace) -> Processor:
    from netapp.builtin_processors import BUILTIN, TRACKING_INSTALL
    from netapp.models.options import detector_config
    from netapp.models.source import resolve_model

    if not args.model:
        raise ProcessorUnavailable(f"{name} needs --model (an ONNX file or an http(s) URL)")
    model_path = resolve_model(args.model, args.sha256, timeout_s=args.download_timeout)
    config = detector_config(args, str(model_path))
    try:
        processor = BUILTIN[name](config)
        processor.load()  # fail at start-up with a clear message, not on the first frame (a second load() is free)
    except ImportError as exc:
        raise ProcessorUnavailable(f"--processor {name} needs the module {exc.name}: {TRACKING_INSTALL}") from exc
    return processor


def processor_class(spec: str) -> type[Processor]:
    """`package.module:Class` -> the class; ProcessorUnavailable saying what is wrong."""
    module_name, _, class_name = spec.partition(":")
    if not module_name or not class_name:
        from netapp.builtin_processors import BUILTIN

        names = ", ".join(sorted(BUILTIN))
        raise ProcessorUnavailable(f"unknown processor {spec!r}: give one of {names}, or package.module:Class")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ProcessorUnavailable(
            f"cannot import {module_name!r} for --processor {spec}: {exc} (is it installed or on PYTHONPATH?)"
        ) from exc
    cls = getattr(module, class_name, None)
    if cls is None:
        raise ProcessorUnavailable(f"module {module_name!r} has no {class_name!r} (--processor {spec})")
    if not (isinstance(cls, type) and issubclass(cls, Processor)):
        raise ProcessorUnavailable(f"--processor {spec} is not a subclass of netapp.sdk.Processor")
    return cls


def build_processor(args: argparse.Namespace) -> Processor:
    """The processor the command line asks for (not loaded yet)."""
    from netapp.builtin_processors import BUILTIN, DEFAULT

    spec = args.processor or DEFAULT
    if spec in BUILTIN:
        return _built_in(spec, args)
    cls = processor_class(spec)
    if args.model:
        raise ProcessorUnavailable(f"--model is for the built-in processors; {spec} loads its own weights in load()")
    try:
        return cls()
    except TypeError as exc:
        raise ProcessorUnavailable(f"{spec} must be constructible with no arguments: {exc}") from exc
