"""`netapp rollout status URL`: a netapp's model rollout, as GET /rollout reports it (docs/rollouts.md). Imports no
server code: it runs wherever the robot client does."""

from __future__ import annotations

import argparse
import json
from typing import Any

TIMEOUT_S = 10.0
MAX_BYTES = 64 * 1024  # a rollout's state is a few hundred bytes


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="rollout_command", metavar="ACTION", required=True)
    status = sub.add_parser("status", help="print the rollout's phase, comparison and reason")
    status.add_argument("url", help="the netapp's URL, e.g. http://127.0.0.1:5896")
    status.add_argument("--json", action="store_true", help="print GET /rollout's JSON as it is")


def describe(state: dict[str, Any]) -> str:
    """A rollout's state in a few lines (pure)."""
    if state.get("phase") == "none":
        return f"no rollout: serving {state.get('serving')}"
    p95 = state.get("p95_ms") or {}
    agreement = state.get("agreement")
    skipped = state.get("skipped") or {}
    lines = [
        f"phase:      {state.get('phase')}",
        f"candidate:  {state.get('model')}",
        f"serving:    {state.get('serving')}",
        f"compared:   {state.get('frames_compared')} frames"
        f" (skipped: {skipped.get('budget', 0)} over budget, {skipped.get('busy', 0)} busy)",
        f"agreement:  {'-' if agreement is None else f'{agreement:.3f}'} (F1 of matched boxes)",
        f"p95:        {_ms(p95.get('current'))} current, {_ms(p95.get('candidate'))} candidate",
        f"errors:     {state.get('errors')}",
    ]
    if state.get("reason"):
        lines.append(f"reason:     {state['reason']}")
    return "\n".join(lines)


def _ms(value: Any) -> str:
    return "-" if value is None else f"{value:.1f} ms"


def run(args: argparse.Namespace) -> int:
    import logging

    import requests

    log = logging.getLogger("netapp.rollout")
    url = args.url.rstrip("/") + "/rollout"
    try:
        response = requests.get(url, timeout=TIMEOUT_S, stream=True)
        body = response.raw.read(MAX_BYTES + 1, decode_content=True)
    except requests.RequestException as exc:
        log.error("cannot reach %s: %s (is the netapp running there?)", url, exc)
        return 1
    if response.status_code != 200 or len(body) > MAX_BYTES:
        log.error("%s answered %d: is this a netapp of this version?", url, response.status_code)
        return 1
    try:
        state = json.loads(body)
    except ValueError:
        log.error("%s did not answer JSON: is this a netapp?", url)
        return 1
    print(json.dumps(state, indent=2) if args.json else describe(state))
    return 0
