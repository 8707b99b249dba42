"""`netapp model inspect FILE [--json]`: what the netapp recognises in a model, and why, before serving it."""

from __future__ import annotations

import argparse
import json
import sys

from netapp.models.options import add_reading_arguments


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="model_command", metavar="ACTION", required=True)
    inspect = sub.add_parser("inspect", help="print a model's card: family, task, input, classes, outputs and why")
    inspect.add_argument("file", help="the ONNX model file")
    inspect.add_argument("--json", action="store_true", help="the card as JSON")
    add_reading_arguments(inspect)


def run(args: argparse.Namespace) -> int:
    from netapp.models.reading import read_model

    try:
        _, card = read_model(args.file, task=args.task, layout=args.layout, labels=args.labels)
    except ValueError as exc:  # ModelRefused and a bad labels file: one line
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(card.to_dict(), indent=1) if args.json else card.text())
    return 0
