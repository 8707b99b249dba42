"""Measure each profile through the emulator and print a Markdown table.

A local echo/sink/source server (127.0.0.1) answers three request kinds, chosen by the first
byte of a connection: ``E`` echo, ``U<n>`` swallow n bytes then answer ``OK``, ``D<n>`` send n
bytes. Per profile we measure connect() time, the first echo on a fresh connection (a real link
needs 2 RTT for connect + request), small-message RTT p50/p95 and bulk throughput each way.
"""

from __future__ import annotations

import socket
import socketserver
import statistics
import struct
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass

from .emulator import LinkEmulator
from .profiles import PROFILES, LinkProfile

_HDR = struct.Struct("!cQ")
_BUF = 256 << 10


def _recv_exact(sock: socket.socket, n: int) -> bytes:
    parts, got = [], 0
    while got < n:
        chunk = sock.recv(min(_BUF, n - got))
        if not chunk:
            raise ConnectionError(f"peer closed after {got} of {n} bytes")
        parts.append(chunk)
        got += len(chunk)
    return b"".join(parts)


class _Handler(socketserver.BaseRequestHandler):
    def handle(self) -> None:
        sock: socket.socket = self.request
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        kind, n = _HDR.unpack(_recv_exact(sock, _HDR.size))
        if kind == b"E":
            while data := sock.recv(_BUF):
                sock.sendall(data)
        elif kind == b"U":
            left = n
            while left:
                data = sock.recv(min(_BUF, left))
                if not data:
                    return
                left -= len(data)
            sock.sendall(b"OK")
        elif kind == b"D":
            block = bytes(_BUF)
            left = n
            while left:
                k = min(left, _BUF)
                sock.sendall(block[:k])
                left -= k


class TestServer(socketserver.ThreadingTCPServer):
    """Echo / sink / source server on 127.0.0.1 with an ephemeral port, in a daemon thread."""

    daemon_threads = True
    allow_reuse_address = True

    def __init__(self) -> None:
        super().__init__(("127.0.0.1", 0), _Handler)
        self._thread = threading.Thread(target=self.serve_forever, daemon=True)

    def __enter__(self) -> TestServer:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()
        self.server_close()


@dataclass
class Measurement:
    profile: LinkProfile
    mode: str
    connect_ms: float
    first_echo_ms: float
    rtt_p50_ms: float
    rtt_p95_ms: float
    up_mbit: float
    down_mbit: float
    loss_up_pct: float | None
    loss_down_pct: float | None


def describe_mode(emu: LinkEmulator) -> str:
    """``netns (tbf, nft)``, ``netns (tbf; loss in userspace)``, ``userspace`` or ``passthrough``."""
    if emu.mode != "netns":
        return str(emu.mode)
    kernel = [k for k, on in (("tbf", emu.kernel_rate), ("nft", emu.kernel_loss)) if on]
    user = [k for k, on in (("rate", not emu.kernel_rate), ("loss", not emu.kernel_loss)) if on]
    text = ", ".join(kernel)
    if user:
        text += ("; " if text else "") + " + ".join(user) + " in userspace"
    return f"netns ({text})"


def _connect(addr: tuple[str, int], kind: bytes, n: int = 0) -> socket.socket:
    sock = socket.create_connection(addr, timeout=30)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    sock.sendall(_HDR.pack(kind, n))
    return sock


def _bulk_bytes(rate_mbit: float | None, seconds: float) -> int:
    # Unshaped links are limited by the relay's CPU; 32 MiB is plenty to time them.
    if rate_mbit is None:
        return 32 << 20
    return min(32 << 20, int(rate_mbit * 1e6 / 8 * seconds))


def measure(
    profile: LinkProfile, server: tuple[str, int], *, samples: int = 50, bulk_seconds: float = 1.5, mode: str = "auto"
) -> Measurement:
    """Run all probes through one emulator instance of ``profile``."""
    emu = LinkEmulator(profile, server, mode=mode)  # type: ignore[arg-type]
    with emu as addr:
        emu_mode = describe_mode(emu)
        t0 = time.perf_counter()
        sock = socket.create_connection(addr, timeout=30)
        connect_ms = (time.perf_counter() - t0) * 1000
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.sendall(_HDR.pack(b"E", 0) + b"ping")
        _recv_exact(sock, 4)
        first_echo_ms = (time.perf_counter() - t0) * 1000

        msg = b"x" * 64
        rtts = []
        for _ in range(samples):
            t = time.perf_counter()
            sock.sendall(msg)
            _recv_exact(sock, len(msg))
            rtts.append((time.perf_counter() - t) * 1000)
        sock.close()

        n_up = _bulk_bytes(profile.rate_mbit_up, bulk_seconds)
        with _connect(addr, b"U", n_up) as s:
            payload = bytes(_BUF)
            t = time.perf_counter()
            left = n_up
            while left:
                k = min(left, _BUF)
                s.sendall(payload[:k])
                left -= k
            _recv_exact(s, 2)
            up_mbit = n_up * 8 / (time.perf_counter() - t) / 1e6

        n_down = _bulk_bytes(profile.rate_mbit_down, bulk_seconds)
        t = time.perf_counter()
        with _connect(addr, b"D", n_down) as s:
            _recv_exact(s, n_down)
            down_mbit = n_down * 8 / (time.perf_counter() - t) / 1e6

        stats = emu.loss_stats()

    def pct(lost_total: tuple[int, int]) -> float | None:
        lost, total = lost_total
        return 100 * lost / total if total else None

    rtts.sort()
    return Measurement(
        profile,
        emu_mode,
        connect_ms,
        first_echo_ms,
        statistics.median(rtts),
        rtts[min(len(rtts) - 1, int(0.95 * len(rtts)))],
        up_mbit,
        down_mbit,
        pct(stats["up"]),
        pct(stats["down"]),
    )


def _fmt_pct(v: float | None) -> str:
    return "-" if v is None else f"{v:.2f}"


def _fmt_rate(r: float | None) -> str:
    return "-" if r is None else f"{r:g}"


def markdown_table(rows: Iterable[Measurement]) -> str:
    """Configured figures next to measured ones; expected RTT is 2 x one-way delay."""
    head = (
        "| profile | mode | delay ms (one-way) | jitter ms "
        "| loss % (cfg / meas up, down) | connect() ms "
        "| first echo ms (expect 4 x delay) | RTT p50 / p95 ms (expect 2 x delay) "
        "| up Mbit/s (cfg / meas) | down Mbit/s (cfg / meas) |\n"
        "|---|---|---|---|---|---|---|---|---|---|"
    )
    lines = [head]
    for m in rows:
        p = m.profile
        lines.append(
            f"| {p.name} | {m.mode} | {p.delay_ms:g} | {p.jitter_ms:g} "
            f"| {p.loss_pct:g} / {_fmt_pct(m.loss_up_pct)}, {_fmt_pct(m.loss_down_pct)} "
            f"| {m.connect_ms:.2f} | {m.first_echo_ms:.1f} "
            f"| {m.rtt_p50_ms:.1f} / {m.rtt_p95_ms:.1f} "
            f"| {_fmt_rate(p.rate_mbit_up)} / {m.up_mbit:.1f} "
            f"| {_fmt_rate(p.rate_mbit_down)} / {m.down_mbit:.1f} |"
        )
    return "\n".join(lines)


def run_check(
    profiles: Iterable[str] | None = None, mode: str = "auto", samples: int = 50, bulk_seconds: float = 1.5
) -> str:
    """Measure the named profiles (all by default) and return the Markdown table."""
    names = list(profiles) if profiles else list(PROFILES)
    rows = []
    with TestServer() as srv:
        host, port = srv.server_address[:2]
        server = (str(host), int(port))
        for name in names:
            rows.append(measure(PROFILES[name], server, samples=samples, bulk_seconds=bulk_seconds, mode=mode))
    return markdown_table(rows)
