"""Which WebSocket client the robot's `frames` transport uses: websockets (sync) vs websocket-client, measured.

    flock /tmp/heavy.lock python -m bench.ws_clients --messages 2000 --size 30000

A server in another process (websockets, asyncio) answers every binary message with a 300-byte text message, as a
netapp answers a frame with its result. The client sends one message of `--size` bytes (a 640x480 JPEG is about
30 KB), waits for the answer, and so on: the round trip, and the client process's CPU per message, for each library
(interleaved, `--repeat` times; medians). Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import asyncio
import multiprocessing
import os
import statistics
import time

ANSWER = "x" * 300


def serve(port_out: multiprocessing.Queue) -> None:
    from websockets.asyncio.server import serve as ws_serve

    async def echo(ws) -> None:
        async for _ in ws:
            await ws.send(ANSWER)

    async def main() -> None:
        async with ws_serve(echo, "127.0.0.1", 0, max_size=None, compression=None) as server:
            port_out.put(server.sockets[0].getsockname()[1])
            await asyncio.Future()

    asyncio.run(main())


def with_websockets(url: str, payload: bytes, count: int) -> tuple[float, float]:
    from websockets.sync.client import connect

    with connect(url, compression=None, max_size=None) as ws:
        return _timed(lambda: (ws.send(payload), ws.recv()), count)


def with_websocket_client(url: str, payload: bytes, count: int) -> tuple[float, float]:
    import websocket

    ws = websocket.create_connection(url)
    try:
        return _timed(lambda: (ws.send_binary(payload), ws.recv()), count)
    finally:
        ws.close()


def _timed(round_trip, count: int) -> tuple[float, float]:
    """(median round trip in µs, client CPU per message in µs)."""
    for _ in range(50):
        round_trip()
    times = []
    cpu0 = time.process_time()
    for _ in range(count):
        t0 = time.perf_counter()
        round_trip()
        times.append(time.perf_counter() - t0)
    cpu = time.process_time() - cpu0
    return statistics.median(times) * 1e6, cpu / count * 1e6


CLIENTS = {"websockets.sync": with_websockets, "websocket-client": with_websocket_client}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--messages", type=int, default=2000)
    parser.add_argument("--size", type=int, default=30000)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    ports: multiprocessing.Queue = multiprocessing.Queue()
    server = multiprocessing.Process(target=serve, args=(ports,), daemon=True)
    server.start()
    url = f"ws://127.0.0.1:{ports.get(timeout=10)}"
    payload = os.urandom(args.size)
    runs: dict[str, list[tuple[float, float]]] = {name: [] for name in CLIENTS}
    try:
        for _ in range(args.repeat):
            for name, client in CLIENTS.items():
                runs[name].append(client(url, payload, args.messages))
    finally:
        server.terminate()
    print(f"| client | round trip p50 (µs) | client CPU per message (µs) |  ({args.size}-byte messages)")
    print("|---|---|---|")
    for name, results in runs.items():
        rtt = statistics.median(r[0] for r in results)
        cpu = statistics.median(r[1] for r in results)
        print(f"| {name} | {rtt:.0f} | {cpu:.0f} |")


if __name__ == "__main__":
    main()
