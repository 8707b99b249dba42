"""Switchover benchmark: from the moment a robot's latency crosses its budget to the robot on the new pool.

    python -m bench.switchover --model ../shared/models/yolox_nano.onnx --runs 5 [--modes cold,standby,route]

The middleware (local backend, so each pool, edge and cloud, is a netapp process on this machine) runs in this
process; a robot deploys on edge and streams 640x480 JPEG frames at 10 FPS over Socket.IO, reporting its p95
latency every 0.5 s against its budget (1000 ms: well within). After a few seconds of streaming, the robot's budget
drops to half the latency it measures (its control loop needs answers faster than edge gives them): it is over
budget, and the middleware decides (after --sustain seconds over budget), starts a netapp on cloud, moves the robot
once that one is Ready and releases edge. Each run prints the time from the crossing to the robot's client on the
cloud URL and to its first result from there, the middleware's own decision-to-move time, and frames lost.

Three modes, a column each: `cold` (the above: the cloud netapp starts after the decision), `standby` (the catalogue
keeps a warm standby on the robot's next-best placement: the decision moves the robot into a netapp already Ready)
and `route` (the robot told the middleware, when it started streaming, that it would be on cloud at the crossing:
the middleware readied cloud at once and moved the robot just before; a negative time is a move done before the
crossing). The client moves make before break (`NetAppClient.move_to`: frames hedged across both netapps until the
new one answers).
"""

from __future__ import annotations

import argparse
import random
import statistics
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from netapp_middleware.switchover.ahead import AheadPolicy
from netapp_middleware.switchover.decision import SwitchPolicy

from bench.robot import robot_jpeg
from netapp.client.middleware import MiddlewareClient
from netapp.serve_process import free_port

ROOT = Path(__file__).resolve().parent.parent

ROBOT, SECRET = "robot-bench", "bench-secret"
MODES = ("cold", "standby", "route")
REPORT_EVERY_S = 0.5  # how often the robot reports its latency


class Middleware:
    """The middleware on a loopback port, in a thread (uvicorn), with a local backend and a switchover policy.
    `url_for`: the local backend's hook for where robots reach a pool's netapp (bench/linkemu/pools.py)."""

    def __init__(
        self,
        model: str,
        policy: SwitchPolicy,
        *,
        standby: bool = False,
        placements: Sequence[str] = ("edge", "cloud"),
        url_for: Callable[[str, str], str] | None = None,
        ahead: AheadPolicy | None = None,
        catalogue: dict[str, Any] | None = None,
        idle_poll_s: float = 1.0,
    ) -> None:
        """`catalogue`: the apps (default: the built-in ones); `idle_poll_s`: the local backend's (bench/wake.py)."""
        import uvicorn
        from netapp_middleware.app import create_app
        from netapp_middleware.auth import RobotRegistry, TokenSigner, hash_secret
        from netapp_middleware.backends.local import LocalBackend
        from netapp_middleware.catalogue import DEFAULT_CATALOGUE, parse_catalogue
        from netapp_middleware.deployments import Registry
        from netapp_middleware.services import Services
        from netapp_middleware.switchover import Switchover

        self.backend = LocalBackend(model=model, url_for=url_for, idle_poll_s=idle_poll_s)
        self.created: list[tuple[float, str | None]] = []  # (when, placement) of each netapp the middleware started
        create = self.backend.create

        async def created(name: str, app: str, placement: str | None, *args: Any) -> None:
            self.created.append((time.monotonic(), placement))
            await create(name, app, placement, *args)

        self.backend.create = created  # type: ignore[method-assign]
        apps = catalogue or DEFAULT_CATALOGUE
        if standby:
            apps = {"object-detection": {**DEFAULT_CATALOGUE["object-detection"], "standby": "nextBest"}}
        catalogue = parse_catalogue(apps)
        robots = {ROBOT: hash_secret(SECRET, n=2**10)}
        registry = Registry(self.backend)
        services = Services(
            registry=registry,
            robots=RobotRegistry(lambda: robots),
            signer=TokenSigner(),
            catalogue=lambda: catalogue,
            switchover=Switchover(
                registry,
                lambda: catalogue,
                list(placements),
                policy,
                min_interval_s=0.1,
                # A netapp started ahead of a move (or for a route) goes 1 s after no robot needs it: the next run
                # starts cold (`wait_cold`).
                ahead=ahead or AheadPolicy(min_dwell_s=0.0, warm_lead_s=60.0, idle_grace_s=1.0),
            ),
        )
        self.registry = registry
        port = free_port()
        self.url = f"http://127.0.0.1:{port}"
        config = uvicorn.Config(create_app(services), host="127.0.0.1", port=port, log_level="warning")
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, daemon=True)

    def wait_cold(self, timeout_s: float = 60.0) -> None:
        """Wait until no netapp of the last run is left (a cold run must start nothing warm on cloud)."""
        deadline = time.monotonic() + timeout_s
        while self.registry.holds() or self.backend.pids():
            if time.monotonic() > deadline:
                raise RuntimeError(f"netapps of the last run still there after {timeout_s:.0f} s")
            time.sleep(0.1)  # polling the middleware's own state from the bench's thread

    def __enter__(self) -> Middleware:
        self.thread.start()
        deadline = time.monotonic() + 30
        while not self.server.started:
            if time.monotonic() > deadline or not self.thread.is_alive():
                raise RuntimeError("the middleware did not start")
            time.sleep(0.05)
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(30)


def one_run(
    mw_url: str,
    frame: bytes,
    budget_ms: float,
    warmup_s: float,
    fps: float,
    mode: str,
    created: Sequence[tuple[float, str | None]] = (),
) -> dict[str, Any]:
    """`created`: (when, placement) of the netapps the middleware starts, to time its decision to start one."""
    budget = {"ms": budget_ms}
    with MiddlewareClient(mw_url, ROBOT, SECRET) as mw:
        edge = mw.deploy("object-detection", placement="edge", timeout=120)
        if mode == "standby":  # the catalogue's warm netapp on cloud is up before the robot needs it
            deadline = time.monotonic() + 120
            while not any(s["placement"] == "cloud" and s["phase"] == "Ready" for s in mw.standbys()["standbys"]):
                if time.monotonic() > deadline:
                    raise RuntimeError("no warm standby on cloud within 120 s")
                time.sleep(0.05)
        arrivals: list[tuple[float, str | None]] = []  # (when, which netapp) of each result
        switched: list[float] = []
        with mw.netapp_client(
            edge, budget_ms=lambda: budget["ms"], report_every_s=REPORT_EVERY_S, transport="ws"
        ) as client:
            client.on_result = lambda result: arrivals.append((time.monotonic(), result.source))
            stop = threading.Event()

            def stream() -> None:
                period = 1.0 / fps
                next_at = time.monotonic()
                while not stop.is_set():
                    client.send(frame)
                    if not switched and client.url != edge.url:
                        switched.append(time.monotonic())
                    next_at += period
                    stop.wait(max(0.0, next_at - time.monotonic()))

            sender = threading.Thread(target=stream, daemon=True)
            sender.start()
            try:
                # The crossing falls anywhere between two reports (a fixed warm-up would put it at the same place).
                eta = time.time() + warmup_s + random.uniform(0.0, REPORT_EVERY_S)
                if mode == "route":  # the robot says where it is heading: on cloud at the crossing
                    mw.route(edge, [("cloud", eta)])
                time.sleep(max(0.0, eta - time.time()))
                with client.stats.lock:
                    recent = client.stats.latencies_ms[-25:]
                measured = statistics.median(recent)
                if mode != "route" and mw.status(edge)["history"]:
                    raise RuntimeError(f"moved before the budget changed: raise --budget-ms above {measured:.0f}")
                budget["ms"] = measured / 2  # the robot now needs answers twice as fast as edge gives them
                crossed = time.monotonic()
                lost_before = client.stats.lost
                deadline = crossed + 120
                while not switched or not any(source not in (None, edge.url) for _, source in arrivals):
                    if time.monotonic() > deadline:
                        raise RuntimeError("the robot was not moved within 120 s")
                    time.sleep(0.005)
                first_result = next(t for t, source in arrivals if source not in (None, edge.url))
                time.sleep(1.0)
            finally:
                stop.set()
                sender.join(5)
            history = mw.status(edge)["history"]
            started = [at - crossed for at, placement in created if placement == "cloud" and at >= crossed]
            return {
                "to_start_s": started[0] if started else float("nan"),  # nan: none started (a standby, a route)
                "edge_p50_ms": measured,
                "to_switch_s": switched[0] - crossed,
                "to_result_s": first_result - crossed,
                "decision_to_move_s": history[0]["seconds"] if history else float("nan"),
                "lost": client.stats.lost - lost_before,
                "to": history[0]["to"] if history else None,
                "why": trigger(history[0]["message"]) if history else "?",
            }


def trigger(message: str) -> str:
    """What moved the robot, from its move's message: its route, a rising trend, a breach into a warm netapp (its
    shorter sustain window), or a sustained breach."""
    if "its route" in message:
        return "route"
    if "rising" in message:
        return "trend"
    return "breach into a warm netapp" if "a netapp is Ready there" in message else "sustained breach"


def robot_args(parser: argparse.ArgumentParser, modes: Sequence[str]) -> None:
    """The options every robot-and-middleware bench takes: the model, the frame, the frame rate and the modes."""
    parser.add_argument("--model", default=str(ROOT.parent / "shared/models/yolox_nano.onnx"))
    parser.add_argument("--image", default=str(ROOT.parent / "shared/media/dog.jpg"), help="the JPEG frame sent")
    parser.add_argument("--fps", type=float, default=10.0)
    parser.add_argument("--modes", default=",".join(modes), help=f"some of {', '.join(modes)} (default all)")


def robot_frame(args: argparse.Namespace, modes: Sequence[str]) -> tuple[bytes, list[str]] | None:
    """The 640x480 JPEG frame the robot sends and the modes asked for; None, after a line saying why, when a file is
    missing or a mode unknown."""
    for path, what in ((args.model, "--model"), (args.image, "--image")):
        if not Path(path).is_file():
            print(f"{what} {path} does not exist: give one (make install fetches nothing; see README.md#set-up)")
            return None
    asked = [m.strip() for m in args.modes.split(",") if m.strip()]
    if not asked or set(asked) - set(modes):
        print(f"--modes: give some of {', '.join(modes)}")
        return None
    import cv2

    image = cv2.resize(cv2.imread(args.image), (640, 480))
    return robot_jpeg(image), asked


def print_table(
    corner: str,
    rows: dict[str, list[dict[str, Any]]],
    lines: Sequence[tuple[str, str, Callable[[list[float]], float], str]],
) -> None:
    """A markdown table, a column per mode (`rows`' keys): each line (key, label, its worst, format) gives the median
    and the worst of the mode's runs."""
    print(f"| {corner} | " + " | ".join(rows) + " |")
    print("|---|" + "---|" * len(rows))
    for key, label, worst, fmt in lines:
        cells = []
        for runs in rows.values():
            values = [r[key] for r in runs]
            cells.append(f"{statistics.median(values):{fmt}} / {worst(values):{fmt}}")
        print(f"| {label} | " + " | ".join(cells) + " |")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    robot_args(parser, MODES)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument(
        "--budget-ms", type=float, default=1000.0, help="the robot's budget before it tightens (default 1000)"
    )
    parser.add_argument("--sustain", type=float, default=2.0, help="seconds over budget before a move (default 2)")
    parser.add_argument(
        "--warm-sustain",
        type=float,
        default=0.0,
        help="seconds over budget before a move into a netapp already Ready (default 0: the first report over it)",
    )
    parser.add_argument("--warmup", type=float, default=4.0, help="seconds of streaming on edge first")
    args = parser.parse_args()
    asked = robot_frame(args, MODES)
    if asked is None:
        return 2
    frame, modes = asked
    rows: dict[str, list[dict[str, Any]]] = {}
    for mode in modes:
        with Middleware(
            args.model,
            SwitchPolicy(sustain_s=args.sustain, warm_sustain_s=args.warm_sustain, min_dwell_s=0.0),
            standby=mode == "standby",
        ) as middleware:
            for run in range(args.runs):
                if mode == "cold":
                    middleware.wait_cold()
                row = one_run(middleware.url, frame, args.budget_ms, args.warmup, args.fps, mode, middleware.created)
                rows.setdefault(mode, []).append(row)
                print(
                    f"{mode} run {run + 1}: edge p50 {row['edge_p50_ms']:.0f} ms; crossing -> cloud netapp started "
                    f"{row['to_start_s']:.2f} s, robot on {row['to']} "
                    f"{row['to_switch_s']:.2f} s, first result there {row['to_result_s']:.2f} s "
                    f"(middleware: decision -> moved {row['decision_to_move_s']:.2f} s, on a {row['why']}); "
                    f"frames lost {row['lost']}",
                    flush=True,
                )
    print(
        f"\nsustain {args.sustain:g} s (into a warm netapp {args.warm_sustain:g} s), "
        f"reports every {REPORT_EVERY_S:g} s (the crossing at a random point between two), "
        f"{args.fps:g} FPS, {args.runs} runs per mode"
    )
    print("(median / max; a negative time: done before the crossing)\n")
    print_table(
        "from the crossing to",
        rows,
        [
            ("to_start_s", "the cloud netapp started (the decision)", max, ".2f"),
            ("to_switch_s", "the robot's client on the cloud URL", max, ".2f"),
            ("to_result_s", "its first result from cloud", max, ".2f"),
            ("decision_to_move_s", "(middleware) decision to move done", max, ".2f"),
            ("lost", "frames lost at the switch", max, "g"),
        ],
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
