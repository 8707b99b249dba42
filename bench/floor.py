"""The floor of this machine: the least a robot in one process and a model in another can add per frame, with no
framework at all, beside `direct` and the netapp's transports, in one interleaved run.

    python -m bench.floor --fps 25 --duration 6 --repeat 3
    python -m bench.floor --floors inline,thread,asyncio --transports frames,ws --repeat 4

A floor server is a few lines of Python over a plain TCP socket: the robot sends a 4-byte length and the JPEG, the
server decodes, letterboxes and runs the same detector as `direct` and the netapp, and answers a 4-byte length and
the result's JSON (its detections and the model's time, as the netapp's result carries them). Three shapes:

- `inline`: one thread reads the frame, runs it and writes the answer: no hand-off between threads at all;
- `thread`: a reader thread hands the frame to a worker thread, which runs it and writes the answer: one hand-off;
- `asyncio`: uvloop reads the frame, a one-thread executor runs it, the loop writes the answer: the netapp's two
  hand-offs (loop to lane, lane to loop) and its GIL switch interval, without uvicorn, the WebSocket or the pipeline.

What `frames` adds over `asyncio` is the netapp's own code (WebSocket, pipeline, counting); what `asyncio` adds over
`inline` is the hand-offs between threads; what `inline` adds over `direct` is the kernel, two processes on the
machine's cores and the robot's side. Writes table.md and runs.json under results/floor-<time>/.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import queue
import socket
import statistics
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

from bench.netapps import VARIANTS_HELP, netapp_process, parse_variants, start_run
from bench.transports import add_model_threads, findings, fmt, merge_repeats, model_threads_serve_args, run_robot, table

ROOT = Path(__file__).resolve().parent.parent
FLOORS = ("inline", "thread", "asyncio")
LENGTH = struct.Struct("!I")
MAX_FRAME = 8 << 20  # a benchmark's own robot, but a bound all the same


def recv_exactly(sock: socket.socket, n: int) -> bytes:
    data = bytearray(n)
    view = memoryview(data)
    got = 0
    while got < n:
        k = sock.recv_into(view[got:])
        if not k:
            raise ConnectionError("peer closed")
        got += k
    return bytes(data)


def recv_message(sock: socket.socket) -> bytes:
    (n,) = LENGTH.unpack(recv_exactly(sock, LENGTH.size))
    if n > MAX_FRAME:
        raise ValueError(f"message of {n} bytes")
    return recv_exactly(sock, n)


def framed(payload: bytes) -> bytes:
    return LENGTH.pack(len(payload)) + payload


def load_runner(model: str, threads: int) -> Callable[[bytes], bytes]:
    """frame bytes -> the answer's bytes: what `direct` does (bench/robot.py's `detector_answer`), the result's JSON
    with its detections and the model's time, as the netapp's result carries them."""
    from bench.robot import detector_answer

    answer = detector_answer(model, threads)

    def run(frame: bytes) -> bytes:
        detections, model_ms = answer(frame)
        return framed(json.dumps({"detections": detections, "inference_ms": model_ms}).encode())

    return run


def serve_inline(listener: socket.socket, run) -> None:
    while True:
        conn, _ = listener.accept()
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        with conn, contextlib.suppress(ConnectionError):
            while True:
                conn.sendall(run(recv_message(conn)))


def serve_thread(listener: socket.socket, run) -> None:
    frames: queue.SimpleQueue = queue.SimpleQueue()

    def worker() -> None:
        while True:
            conn, frame = frames.get()
            with contextlib.suppress(OSError):
                conn.sendall(run(frame))

    threading.Thread(target=worker, daemon=True).start()
    while True:
        conn, _ = listener.accept()
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        with conn, contextlib.suppress(ConnectionError):
            while True:
                frames.put((conn, recv_message(conn)))


def serve_asyncio(listener: socket.socket, run) -> None:
    import concurrent.futures

    import uvloop

    from netapp.server.runner import GIL_SWITCH_S

    sys.setswitchinterval(GIL_SWITCH_S)
    lane = concurrent.futures.ThreadPoolExecutor(1)

    async def robot(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        loop = asyncio.get_running_loop()
        with contextlib.suppress(asyncio.IncompleteReadError, ConnectionError):
            while True:
                (n,) = LENGTH.unpack(await reader.readexactly(LENGTH.size))
                if n > MAX_FRAME:
                    break
                frame = await reader.readexactly(n)
                writer.write(await loop.run_in_executor(lane, run, frame))
        writer.close()

    async def main() -> None:
        server = await asyncio.start_server(robot, sock=listener)
        async with server:
            await server.serve_forever()

    uvloop.run(main())


def serve(shape: str, model: str, port_file: str, threads: int = 0) -> None:
    """A floor server on a free loopback port, written to `port_file` once the model is loaded and warmed up."""
    run = load_runner(model, threads)
    listener = socket.create_server(("127.0.0.1", 0))
    Path(port_file).write_text(str(listener.getsockname()[1]))
    {"inline": serve_inline, "thread": serve_thread, "asyncio": serve_asyncio}[shape](listener, run)


def robot(args) -> dict:
    """bench/robot.py's `direct` loop (paced, newest frame wins) with each frame sent to a floor server."""
    import resource

    from bench.robot import jpeg_frames, paced_newest

    host, _, port = args.url.removeprefix("tcp://").partition(":")
    size = tuple(int(v) for v in args.size.split("x"))
    frames = jpeg_frames(args.video, args.fps, size, int(args.fps * args.duration))
    sock = socket.create_connection((host, int(port)))
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def answer(frame: bytes) -> tuple[list, float]:
        sock.sendall(framed(frame))
        result = json.loads(recv_message(sock))
        return result["detections"], result["inference_ms"]

    for i in range(args.warmup):  # the server's first few hundred model runs are slower
        answer(frames[i % len(frames)])
    summary = paced_newest(frames, args.fps, answer)
    sock.close()
    return summary | {"peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


@contextlib.contextmanager
def floor_process(shape: str, model: str, out_dir: Path, threads: int = 0):
    """A floor server as its own process; yields (process, port) once it listens."""
    port_file = out_dir / f"{shape}.port"
    server = subprocess.Popen(
        [
            *(sys.executable, "-m", "bench.floor", "serve", shape, "--model", model),
            *("--port-file", str(port_file), "--threads", str(threads)),
        ],
        cwd=ROOT,
    )
    try:
        deadline = time.monotonic() + 120
        while not port_file.exists() or not port_file.read_text():
            if server.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"floor server {shape} did not start")
            time.sleep(0.1)
        yield server, int(port_file.read_text())
    finally:
        server.terminate()
        server.wait(timeout=20)


def robot_command(args, fps: float, port: int) -> list[str]:
    return [
        *(sys.executable, "-m", "bench.floor", "robot", "--url", f"tcp://127.0.0.1:{port}"),
        *("--video", os.path.abspath(args.video), "--fps", str(fps), "--duration", str(args.duration)),
        *("--size", args.size, "--warmup", str(args.robot_warmup)),
    ]


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] in ("serve", "robot"):
        return sub_main(sys.argv[1], sys.argv[2:])
    shared = ROOT.parent / "shared"
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", default=str(shared / "models" / "yolox_nano.onnx"))
    p.add_argument("--video", default=str(shared / "media" / "pedestrians.avi"))
    p.add_argument("--fps", default="25", help="input rates, comma-separated")
    p.add_argument("--duration", type=float, default=6.0, help="seconds per run")
    p.add_argument("--size", default="640x480")
    p.add_argument("--repeat", type=int, default=3, help="runs per configuration, interleaved; medians shown")
    p.add_argument("--floors", default=",".join(FLOORS), help=f"floor servers among {', '.join(FLOORS)}")
    p.add_argument("--transports", default="frames,ws", help="the netapp's transports beside them ('' for none)")
    p.add_argument("--serve-args", default="", help="extra arguments for `netapp serve`")
    p.add_argument("--variants", default="", help=VARIANTS_HELP + "; the floors and direct run once for all")
    p.add_argument("--starts", type=int, default=0, help="times each variant's netapp is started (exec -> /readyz)")
    add_model_threads(p)
    p.add_argument("--warmup", type=float, default=8.0, help="seconds the netapp is streamed to before it is timed")
    p.add_argument("--robot-warmup", type=int, default=100, help="frames a floor robot sends untimed first")
    p.add_argument("--out", default=str(ROOT / "results"))
    p.add_argument("--quick", action="store_true", help="one short run of each row, no warm-up (the tests)")
    args = p.parse_args()
    if args.quick:
        args.duration, args.repeat, args.warmup, args.robot_warmup = 1.5, 1, 0, 5
    args.pre_encode = True
    out_dir = start_run("floor", args.out, (args.model, args.video))
    if out_dir is None:
        return 2
    args.model, args.video = os.path.abspath(args.model), os.path.abspath(args.video)
    shapes = [s for s in args.floors.split(",") if s]
    unknown = set(shapes) - set(FLOORS)
    if unknown:
        print(f"--floors: unknown {', '.join(sorted(unknown))} (choose among {', '.join(FLOORS)})")
        return 2
    transports = [t for t in args.transports.split(",") if t]
    try:
        variants, serve_args = parse_variants(args.variants, args.serve_args.split() + model_threads_serve_args(args))
    except ValueError as exc:
        print(exc)
        return 2
    starts = start_times(args.model, variants, serve_args, args.starts)
    rows = []
    with contextlib.ExitStack() as stack:
        floors = {s: stack.enter_context(floor_process(s, args.model, out_dir, args.model_threads)) for s in shapes}
        netapps = {
            name: stack.enter_context(netapp_process(args.model, serve_args[name], code=code or None))
            for name, code in (variants.items() if transports else ())
        }
        for name, (server, port) in netapps.items():
            if args.warmup > 0:
                run_robot(args, "ws", 25, f"http://127.0.0.1:{port}", server.pid, variants[name], args.warmup)
        for repeat in range(args.repeat):  # interleaved, so slow drifts hit every row alike
            for fps in (float(f) for f in args.fps.split(",")):
                runs = [("", "direct", lambda fps=fps: run_robot(args, "direct", fps, None, None))]
                runs += [
                    (
                        "",
                        f"floor-{s}",
                        lambda s=s, fps=fps: run_robot(
                            args,
                            f"floor-{s}",
                            fps,
                            None,
                            floors[s][0].pid,
                            command=robot_command(args, fps, floors[s][1]),
                        ),
                    )
                    for s in shapes
                ]
                runs += [
                    (
                        name,
                        t,
                        lambda t=t, fps=fps, name=name, server=server, port=port: run_robot(
                            args, t, fps, f"http://127.0.0.1:{port}", server.pid, variants[name] or None
                        ),
                    )
                    for t in transports
                    for name, (server, port) in netapps.items()
                ]
                for variant, name, measure in runs:
                    row = measure() | {"link": "loopback", "variant": variant}
                    rows.append(row)
                    print(
                        f"[{repeat + 1}/{args.repeat}] {variant:6} {name:14} {fps:5g} fps: p50 "
                        f"{fmt(row['latency_ms']['p50'])} ms, outside the model {fmt(row['outside_model_ms'])} ms",
                        file=sys.stderr,
                        flush=True,
                    )
    rows = merge_repeats(rows)
    load = os.getloadavg()[0]
    report = f"{table(rows)}\n\n{findings(rows)}\n{start_table(starts)}\nload average at the end: {load:.2f}\n"
    (out_dir / "table.md").write_text(report)
    (out_dir / "runs.json").write_text(json.dumps(rows, indent=1))
    print(report)
    print(f"written: {out_dir}/table.md, runs.json")
    return 0


def start_times(
    model: str, variants: dict[str, str], serve_args: dict[str, list[str]], count: int
) -> dict[str, list[float]]:
    """Each variant's netapp started `count` times, interleaved: seconds from exec to /readyz answering 200."""
    times: dict[str, list[float]] = {name: [] for name in variants} if count else {}
    for _ in range(count):
        for name, code in variants.items():
            began = time.monotonic()
            with netapp_process(model, serve_args[name], code=code or None):
                times[name].append(time.monotonic() - began)
    return times


def start_table(times: dict[str, list[float]]) -> str:
    """The start-up table: median and range of exec -> /readyz per variant."""
    if not times:
        return ""
    lines = ["| netapp | starts | exec -> /readyz p50 (s) | min | max |", "|---|---|---|---|---|"]
    for name, seconds in times.items():
        lines.append(
            f"| {name or 'this'} | {len(seconds)} | {statistics.median(seconds):.2f} | {min(seconds):.2f} | "
            f"{max(seconds):.2f} |"
        )
    return "\n".join(lines) + "\n"


def sub_main(command: str, argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog=f"python -m bench.floor {command}")
    if command == "serve":
        p.add_argument("shape", choices=FLOORS)
        p.add_argument("--model", required=True)
        p.add_argument("--port-file", required=True)
        p.add_argument("--threads", type=int, default=0, help="onnxruntime's threads (0: every core)")
        a = p.parse_args(argv)
        serve(a.shape, a.model, a.port_file, a.threads)
        return 0
    p.add_argument("--url", required=True, help="tcp://HOST:PORT of a floor server")
    p.add_argument("--video", required=True)
    p.add_argument("--fps", type=float, required=True)
    p.add_argument("--duration", type=float, required=True)
    p.add_argument("--size", default="640x480")
    p.add_argument("--warmup", type=int, default=300)
    print(json.dumps(robot(p.parse_args(argv))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
