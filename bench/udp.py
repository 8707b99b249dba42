"""UDP against TCP under loss (issue 35): `frames` (H.264 over TCP), RTP (H.264 over UDP) and WebRTC (aiortc), 1280x720
at 10 fps, 40 ms round trip, 0/1/3/5 % random loss each way, one robot, a real netapp with YOLOX-Nano.

    flock /tmp/heavy.lock python -m bench.udp --plot docs/udp.png  # docs/benchmarks.md#udp-against-tcp-issue-35
    flock /tmp/heavy.lock python -m bench.udp --losses 3 --rounds 5    # the goal's row only

The path (root, `ip`, `nft`): three network namespaces, robot -- middle -- netapp, joined by veths (one packet per
skb). The middle namespace routes every packet through a TUN device whose reader holds it 20 ms
(`bench/linkemu/tundelay.py`: this kernel has no netem), then drops `loss` % of them (nftables `numgen random` on
what leaves the TUN device), each direction: TCP and UDP see the same delay and loss on the same path. The robot is
`netapp stream` in its namespace; the netapp `netapp serve --rtp-ports` in its own.

Per row (several rounds, the paths interleaved; `bench/udp_report.py` makes the tables and the plot): results/s,
latency p50 and p99 (the robot's: sent to result; the medians of the rounds'), frames never answered with a result
(the robot's frames sent minus its results), and corrupt pictures that reached the model: pictures the netapp's decoder
refused as damaged (`h264_decode_error`, `h264_missing_packet` on its decoder), which a damaged picture that got past
the RTP depacketiser would show as; the decoder never hands such a picture on.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.udp_report import Round, Transport, counters_table, percentile, plot, row, table, tail_table

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared"
ROBOT_ADDR, MIDDLE_C, MIDDLE_S, NETAPP_ADDR = "10.254.1.1", "10.254.1.2", "10.254.2.1", "10.254.2.2"
PORT, RTP_PORTS = 5896, "50000-50007"
DELAY_MS = 20.0  # each way: a 40 ms round trip
# The paths compared, in the table's order: one more is one more entry.
TRANSPORTS = [
    Transport("frames (TCP)", "TCP", ("--transport", "frames", "--codec", "h264")),
    Transport("RTP (UDP)", "UDP", ("--transport", "rtp")),
    Transport("WebRTC (UDP)", "UDP", ("--transport", "webrtc")),  # aiortc both ends (docs/cameras.md#webrtc)
]
COUNTERS = ("netapp_rtp_", "netapp_webrtc_")  # the RTP path's and WebRTC's (`nacked` the same column in both)
QUIET = ("packets_total",)  # counted, but says nothing of recovery
CORRUPT = ("h264_decode_error", "h264_missing_packet")


def run(*args: str, stdin: str | None = None) -> str:
    done = subprocess.run(args, input=stdin, capture_output=True, text=True, timeout=30)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(args)}: {done.stderr.strip()}")
    return done.stdout


class Path3:
    """robot ns -- middle ns (TUN delay, nft loss) -- netapp ns; `close()` deletes them (and all in them)."""

    def __init__(self) -> None:
        tag = f"udpb{os.getpid() % 100000}"
        self.robot, self.middle, self.netapp = f"{tag}-r", f"{tag}-m", f"{tag}-n"
        self.delayer: subprocess.Popen | None = None
        for ns in (self.robot, self.middle, self.netapp):
            run("ip", "netns", "add", ns)
        try:
            self._build()
        except BaseException:
            self.close()
            raise

    def _build(self) -> None:
        r, m, n = self.robot, self.middle, self.netapp
        run("ip", "link", "add", "vr", "netns", r, "type", "veth", "peer", "name", "mr", "netns", m)
        run("ip", "link", "add", "vn", "netns", n, "type", "veth", "peer", "name", "mn", "netns", m)
        for ns, dev, addr in ((r, "vr", ROBOT_ADDR), (m, "mr", MIDDLE_C), (m, "mn", MIDDLE_S), (n, "vn", NETAPP_ADDR)):
            run("ip", "-n", ns, "link", "set", dev, "gso_max_size", "1500", "gso_max_segs", "1")
            run("ip", "-n", ns, "addr", "add", f"{addr}/30", "dev", dev)
            run("ip", "-n", ns, "link", "set", dev, "up")
        for ns in (r, m, n):
            run("ip", "-n", ns, "link", "set", "lo", "up")
        run("ip", "-n", r, "route", "add", "default", "via", MIDDLE_C)
        run("ip", "-n", n, "route", "add", "default", "via", MIDDLE_S)
        for key in ("net.ipv4.ip_forward=1", "net.ipv4.conf.all.rp_filter=0", "net.ipv4.conf.default.rp_filter=0"):
            run("ip", "netns", "exec", m, "sysctl", "-qw", key)
        run("ip", "-n", m, "tuntap", "add", "dev", "tun0", "mode", "tun")
        run("ip", "netns", "exec", m, "sysctl", "-qw", "net.ipv4.conf.tun0.rp_filter=0")
        run("ip", "-n", m, "link", "set", "tun0", "up")
        for dev in ("mr", "mn"):  # what arrives from either side goes to the delayer first
            run("ip", "-n", m, "rule", "add", "iif", dev, "lookup", "100")
        run("ip", "-n", m, "route", "add", "default", "dev", "tun0", "table", "100")
        command = ["ip", "netns", "exec", m, sys.executable, "-m", "bench.linkemu.tundelay", "tun0", str(DELAY_MS)]
        self.delayer = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, text=True)
        assert self.delayer.stdout is not None
        if self.delayer.stdout.readline().strip() != "ready":
            raise RuntimeError("the TUN delayer did not start")
        self.set_loss(0.0)

    def set_loss(self, pct: float) -> None:
        """Drop `pct` % of the packets leaving the delayer (each direction: every packet passes it once)."""
        rule = f'iifname "tun0" numgen random mod 10000 < {round(pct * 100)} drop' if pct > 0 else ""
        ruleset = (
            "table inet udpbench {\n  chain forward { type filter hook forward priority 0; policy accept; }\n}\n"
            "flush chain inet udpbench forward\n" + (f"add rule inet udpbench forward {rule}\n" if rule else "")
        )
        run("ip", "netns", "exec", self.middle, "nft", "-f", "-", stdin=ruleset)

    def close(self) -> None:
        if self.delayer is not None:
            self.delayer.terminate()
            self.delayer.wait(10)
        for ns in (self.robot, self.middle, self.netapp):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=30)


def metrics(path: Path3) -> dict[str, float]:
    text = run("ip", "netns", "exec", path.robot, "curl", "-s", f"http://{NETAPP_ADDR}:{PORT}/metrics")
    rows = (line.rsplit(" ", 1) for line in text.splitlines() if line and not line.startswith("#"))
    return {name: float(value) for name, value in rows}


def corrupt_seen(before: dict[str, float], after: dict[str, float]) -> int:
    total = 0
    for name, value in after.items():
        if name.startswith("netapp_frames_rejected_total") and any(f'reason="{r}"' in name for r in CORRUPT):
            total += int(value - before.get(name, 0.0))
    return total


def rtp_counters(before: dict[str, float], after: dict[str, float]) -> dict[str, float]:
    """The netapp's RTP and WebRTC counters that rose (`nacked`, `dropped:gap`, `results_udp:sent`, `held`, ...): how
    its losses were recovered."""
    out = {}
    for name, value in after.items():
        rise = value - before.get(name, 0.0)
        prefix = next((p for p in COUNTERS if name.startswith(p)), None)
        if prefix and "_total" in name and rise > 0 and not name.endswith(QUIET):
            base, _, label = name.removeprefix(prefix).partition("{")
            value_of_label = label.partition('="')[2].rstrip('"}')
            out[base.removesuffix("_total") + (f":{value_of_label}" if value_of_label else "")] = rise
    return out


def stream(path: Path3, transport: Transport, seconds: float, out: Path) -> Round:
    command = ["ip", "netns", "exec", path.robot, sys.executable, "-m", "netapp", "stream"]
    command += [f"http://{NETAPP_ADDR}:{PORT}", *transport.args, "--source", str(SHARED / "media" / "pedestrians.avi")]
    command += ["--size", "1280x720", "--full-frames", "--adapt", "off", "--fps", "10", "--duration", str(seconds)]
    command += ["--json", "--jsonl", str(out)]
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=seconds + 120)
    if done.returncode != 0:
        raise RuntimeError(
            f"netapp stream failed ({done.returncode}): {done.stdout[:600]} {done.stderr.strip()[-1500:]}"
        )
    summary = json.loads(done.stdout)
    records = [json.loads(line) for line in out.read_text().splitlines() if line.strip()]
    return Round(
        frames_sent=summary["frames_sent"],
        results=summary["results"],
        results_per_s=summary["results_per_s"],
        latencies=[r["latency_ms"] for r in records],
        breakdowns=[r["breakdown_ms"] for r in records if r.get("breakdown_ms")],
    )


def wait_ready(path: Path3, netapp: subprocess.Popen) -> None:
    deadline = time.monotonic() + 120
    while True:  # polling the netapp's readiness from the robot's side of the path
        probe = ["ip", "netns", "exec", path.robot, "curl", "-s", "-o", "/dev/null", "-w", "%{http_code}"]
        code = subprocess.run([*probe, f"http://{NETAPP_ADDR}:{PORT}/readyz"], capture_output=True, text=True)
        if code.stdout == "200":
            return
        if time.monotonic() > deadline or netapp.poll() is not None:
            raise RuntimeError("the netapp did not become ready")
        time.sleep(0.5)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default=str(SHARED / "models" / "yolox_nano.onnx"))
    parser.add_argument("--losses", default="0,1,3,5", help="percent, comma-separated (0,1,3,5)")
    parser.add_argument("--duration", type=float, default=20.0, help="seconds per round (20)")
    parser.add_argument("--rounds", type=int, default=3, help="rounds per row, the paths interleaved (3)")
    parser.add_argument("--paths", default=",".join(t.name for t in TRANSPORTS), help="which paths, by name")
    parser.add_argument("--plot", metavar="FILE.png", help="draw p99 and p50 against loss per path")
    parser.add_argument("--keep", metavar="DIR", help="keep each round's results (JSON lines), the netapp's log here")
    args = parser.parse_args()
    if os.geteuid() != 0:
        print("bench.udp needs root (network namespaces, nftables)", file=sys.stderr)
        return 2
    chosen = [t for t in TRANSPORTS if t.name in args.paths.split(",")]
    if args.keep:
        Path(args.keep).mkdir(parents=True, exist_ok=True)
    load_before = os.getloadavg()
    print(f"load average before: {load_before}", flush=True)
    path = Path3()
    serve = ["ip", "netns", "exec", path.netapp, sys.executable, "-m", "netapp", "serve", "--model", args.model]
    serve += ["--host", NETAPP_ADDR, "--port", str(PORT), "--rtp-ports", RTP_PORTS]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        log = open(Path(tmp) / "netapp.log", "w")  # noqa: SIM115 (closed below)
        netapp = subprocess.Popen(serve, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
        try:
            wait_ready(path, netapp)
            for loss in (float(x) for x in args.losses.split(",")):
                path.set_loss(loss)
                rounds: dict[str, list[Round]] = {t.name: [] for t in chosen}
                for index in range(args.rounds):
                    for transport in chosen:
                        before = metrics(path)
                        got = stream(path, transport, args.duration, Path(tmp) / "results.jsonl")
                        if args.keep:  # what each frame took, to read a tail frame by frame
                            name = f"{loss:g}-{transport.name.split()[0]}-{index + 1}.jsonl"
                            shutil.copyfile(Path(tmp) / "results.jsonl", Path(args.keep) / name)
                        after = metrics(path)
                        got.corrupt, got.counters = corrupt_seen(before, after), rtp_counters(before, after)
                        rounds[transport.name].append(got)
                        p99 = percentile(got.latencies, 99)
                        print(f"{loss:g} % {transport.name} round {index + 1}: p99 {p99:.0f} ms", flush=True)
                rows += [row(loss, t, rounds[t.name]) for t in chosen]
        except RuntimeError:
            log.flush()
            print("the netapp's log ends:\n" + (Path(tmp) / "netapp.log").read_text()[-3000:], file=sys.stderr)
            raise
        finally:
            netapp.terminate()
            netapp.wait(20)
            log.close()
            if args.keep:
                shutil.copyfile(Path(tmp) / "netapp.log", Path(args.keep) / "netapp.log")
            path.close()
    load_after = os.getloadavg()
    print(f"load average after: {load_after}")
    print()
    print(table(rows))
    print()
    print(tail_table(rows))
    print()
    print(counters_table(rows))
    if args.plot:
        title = (
            f"1280x720 10 fps, {2 * DELAY_MS:.0f} ms RTT, {args.rounds} x {args.duration:g} s a point; "
            f"load {load_before[0]:.1f} / {load_after[0]:.1f}"
        )
        plot(rows, args.plot, title)
        print(f"\nthe plot: {args.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
