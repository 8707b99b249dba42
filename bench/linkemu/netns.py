"""Kernel side of the emulator: a pair of network namespaces joined by a veth pair.

Topology (both namespaces are created and deleted by us; nothing is added to the caller's
namespace, so deleting the two namespaces removes the veth pair, the qdiscs and the nft tables):

    ns "<name>-c"  veth 10.254.0.1/30  --tbf (uplink)-->   veth 10.254.0.2/30  ns "<name>-s"
                   nft: random drop of downlink        <--tbf (downlink)--  nft: random drop of uplink

Losses are applied on the receiving side so TCP sees them as packets lost in flight (an nft
drop on the sending host's output hook is reported to the local TCP as an error instead).
Sockets are placed in a namespace by a worker thread that has called setns(2): the network
namespace is per thread, and a socket stays in the namespace it was created in.
"""

from __future__ import annotations

import ctypes
import json
import logging
import os
import re
import shutil
import socket
import subprocess
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

from .profiles import LinkProfile

log = logging.getLogger("linkemu")

CLONE_NEWNET = 0x40000000
NETNS_DIR = "/run/netns"
NS_PREFIX = "lemu"
CLIENT_ADDR = "10.254.0.1"
SERVER_ADDR = "10.254.0.2"
MSS_BYTES = 1448  # TCP payload per segment (timestamps on, 1500-byte MTU)
FRAME_BYTES = 1514  # the same segment as an Ethernet frame, as tbf counts it
# Small fixed timeout for each ip/tc/nft call: they never block on the network.
_CMD_TIMEOUT_S = 10.0

_libc = ctypes.CDLL(None, use_errno=True)
_counter_lock = threading.Lock()
_counter = 0


class NetnsError(RuntimeError):
    """A namespace, link, qdisc or nft command failed."""


def _run(args: list[str], stdin: str | None = None) -> None:
    proc = subprocess.run(args, input=stdin, capture_output=True, text=True, timeout=_CMD_TIMEOUT_S, check=False)
    if proc.returncode != 0:
        raise NetnsError(f"{' '.join(args)} failed ({proc.returncode}): {proc.stderr.strip()}")


@dataclass(frozen=True)
class Capabilities:
    """What the kernel path can do here; ``reason`` explains anything missing."""

    netns: bool
    tbf: bool
    nft: bool
    reason: str = ""


_caps_cache: Capabilities | None = None


def detect_capabilities(refresh: bool = False) -> Capabilities:
    """Probe root, ip/tc/nft and the kernel by building (and deleting) a throwaway namespace pair."""
    global _caps_cache
    if _caps_cache is not None and not refresh:
        return _caps_cache
    reasons: list[str] = []
    if os.geteuid() != 0:
        caps = Capabilities(False, False, False, "not root (network namespaces need CAP_SYS_ADMIN)")
    elif shutil.which("ip") is None:
        caps = Capabilities(False, False, False, "iproute2 'ip' not found")
    else:
        pair = None
        try:
            pair = NetnsPair.create()
        except (NetnsError, OSError, subprocess.SubprocessError) as exc:
            caps = Capabilities(False, False, False, f"cannot create a veth/netns pair: {exc}")
        else:
            tbf = nft = False
            if shutil.which("tc") is None:
                reasons.append("'tc' not found (rate shaped in userspace)")
            else:
                try:
                    pair.add_tbf(pair.client_ns, pair.client_if, 10.0)
                    tbf = True
                except NetnsError as exc:
                    reasons.append(f"tbf unusable ({exc}); rate shaped in userspace")
            if shutil.which("nft") is None:
                reasons.append(
                    "'nft' not found: `apt-get install -y nftables` for kernel packet "
                    "loss; loss emulated in userspace meanwhile"
                )
            else:
                try:
                    pair.set_drop(pair.server_ns, pair.server_if, 1.0)
                    nft = True
                except NetnsError as exc:
                    reasons.append(f"nftables unusable ({exc}); loss emulated in userspace")
            caps = Capabilities(True, tbf, nft, "; ".join(reasons))
        finally:
            if pair is not None:
                pair.destroy()
    _caps_cache = caps
    return caps


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def list_namespaces(prefix: str = NS_PREFIX) -> list[str]:
    """Names of our namespaces (``ip netns list`` filtered by prefix)."""
    try:
        names = os.listdir(NETNS_DIR)
    except FileNotFoundError:
        return []
    return sorted(n for n in names if n.startswith(prefix + "-"))


def sweep_stale() -> list[str]:
    """Delete namespaces left by emulator processes that died without cleaning up (e.g. SIGKILL)."""
    removed = []
    for name in list_namespaces():
        m = re.match(rf"{NS_PREFIX}-(\d+)-", name)
        if m and not _pid_alive(int(m.group(1))):
            try:
                _run(["ip", "netns", "del", name])
                removed.append(name)
            except (NetnsError, OSError, subprocess.SubprocessError) as exc:
                log.warning("could not delete stale namespace %s: %s", name, exc)
    if removed:
        log.info("removed stale namespaces: %s", ", ".join(removed))
    return removed


def _enter_netns(name: str) -> None:
    fd = os.open(os.path.join(NETNS_DIR, name), os.O_RDONLY | os.O_CLOEXEC)
    try:
        if _libc.setns(fd, CLONE_NEWNET) != 0:
            err = ctypes.get_errno()
            raise OSError(err, f"setns({name}): {os.strerror(err)}")
    finally:
        os.close(fd)


@dataclass
class NetnsPair:
    """Two namespaces joined by a veth pair; :meth:`destroy` removes everything."""

    base: str
    client_ns: str
    server_ns: str
    client_if: str
    server_if: str
    _executors: dict[str, ThreadPoolExecutor] = field(default_factory=dict)

    @classmethod
    def create(cls) -> NetnsPair:
        """Build both namespaces, the veth pair and its addresses (impairments: :meth:`shape`)."""
        global _counter
        with _counter_lock:
            _counter += 1
            n = _counter
        pid = os.getpid()
        base = f"{NS_PREFIX}-{pid}-{n}"
        # Interface names must fit IFNAMSIZ (15); they only need to be unique per namespace,
        # but unique names keep `ip link` output readable while a pair is being built.
        tag = f"{pid % 0xFFFFF:x}{n % 0xFFF:x}"
        pair = cls(base, base + "-c", base + "-s", f"lc{tag}", f"ls{tag}")
        try:
            _run(["ip", "netns", "add", pair.client_ns])
            _run(["ip", "netns", "add", pair.server_ns])
            _run(
                [
                    "ip",
                    "link",
                    "add",
                    pair.client_if,
                    "netns",
                    pair.client_ns,
                    "type",
                    "veth",
                    "peer",
                    "name",
                    pair.server_if,
                    "netns",
                    pair.server_ns,
                ]
            )
            for ns, dev, addr in (
                (pair.client_ns, pair.client_if, CLIENT_ADDR),
                (pair.server_ns, pair.server_if, SERVER_ADDR),
            ):
                # One MSS per skb: with TSO/GSO a single nft drop would lose ~45 segments at
                # once and tbf would see 64 KiB bursts.
                _run(["ip", "-n", ns, "link", "set", dev, "gso_max_size", "1500", "gso_max_segs", "1"])
                _run(["ip", "-n", ns, "addr", "add", f"{addr}/30", "dev", dev])
                _run(["ip", "-n", ns, "link", "set", dev, "up"])
                _run(["ip", "-n", ns, "link", "set", "lo", "up"])
        except BaseException:
            pair.destroy()
            raise
        return pair

    def add_tbf(self, ns: str, dev: str, rate_mbit: float) -> None:
        """Shape egress of ``dev`` so TCP goodput is ``rate_mbit`` (token bucket filter)."""
        # tbf counts whole frames; scale so that TCP *goodput* (what the cited measurements
        # report) equals rate_mbit: 1448 payload bytes ride in a 1514-byte frame.
        rate_bps = rate_mbit * 1e6 * FRAME_BYTES / MSS_BYTES
        # Burst must cover at least one timer tick at this rate (and one MTU); the queue
        # holds ~50 ms so TCP on the veth keeps the bucket busy without huge bufferbloat.
        burst = max(16_000, int(rate_bps / 8 * 0.004))
        _run(
            [
                "tc",
                "-n",
                ns,
                "qdisc",
                "replace",
                "dev",
                dev,
                "root",
                "tbf",
                "rate",
                f"{rate_bps:.0f}bit",
                "burst",
                str(burst),
                "latency",
                "50ms",
            ]
        )

    def set_drop(self, ns: str, dev: str, loss_pct: float, down: bool = False) -> None:
        """Drop ``loss_pct`` % of the packets arriving on ``dev`` (nftables ``numgen random``), or all of them while
        ``down``. Creates the table on first use and replaces the rule after; the counters ``lost`` (random drops)
        and ``outage`` (drops while down) keep counting across changes."""
        per_10k = round(loss_pct * 100)
        if down:
            rule = f'iifname "{dev}" counter name "outage" drop'
        elif per_10k > 0:
            rule = f'iifname "{dev}" numgen random mod 10000 < {min(per_10k, 9999)} counter name "lost" drop'
        else:
            rule = ""
        ruleset = (
            "table inet linkemu {\n"
            "  counter lost { }\n"
            "  counter outage { }\n"
            "  chain input { type filter hook prerouting priority -300; policy accept; }\n"
            "}\n"
            "flush chain inet linkemu input\n" + (f"add rule inet linkemu input {rule}\n" if rule else "")
        )
        _run(["ip", "netns", "exec", ns, "nft", "-f", "-"], stdin=ruleset)

    def set_drop_both(self, loss_pct: float, down: bool = False) -> None:
        """:meth:`set_drop` on both receiving sides: the same loss, or the same outage, each way."""
        self.set_drop(self.server_ns, self.server_if, loss_pct, down)
        self.set_drop(self.client_ns, self.client_if, loss_pct, down)

    def shape(self, profile: LinkProfile, caps: Capabilities) -> tuple[bool, bool]:
        """Apply rate and loss in the kernel where possible; return (rate_done, loss_done)."""
        rate_done = loss_done = False
        if caps.tbf:
            if profile.rate_mbit_up is not None:
                self.add_tbf(self.client_ns, self.client_if, profile.rate_mbit_up)
            if profile.rate_mbit_down is not None:
                self.add_tbf(self.server_ns, self.server_if, profile.rate_mbit_down)
            rate_done = True
        if caps.nft:
            if profile.loss_pct > 0:
                self.set_drop_both(profile.loss_pct)
            loss_done = True
        return rate_done, loss_done

    def loss_counters(self) -> dict[str, tuple[int, int]]:
        """``{"up": (dropped, received), "down": ...}`` packets on the veth receive sides."""
        result = {}
        for direction, ns, dev in (("up", self.server_ns, self.server_if), ("down", self.client_ns, self.client_if)):
            out = subprocess.run(
                ["ip", "-n", ns, "-s", "-j", "link", "show", "dev", dev],
                capture_output=True,
                text=True,
                timeout=_CMD_TIMEOUT_S,
                check=True,
            ).stdout
            received = int(json.loads(out)[0]["stats64"]["rx"]["packets"])
            nft = subprocess.run(
                ["ip", "netns", "exec", ns, "nft", "list", "counter", "inet", "linkemu", "lost"],
                capture_output=True,
                text=True,
                timeout=_CMD_TIMEOUT_S,
                check=False,
            )
            m = re.search(r"packets (\d+)", nft.stdout) if nft.returncode == 0 else None
            result[direction] = (int(m.group(1)) if m else 0, received)
        return result

    def _executor(self, ns: str) -> ThreadPoolExecutor:
        ex = self._executors.get(ns)
        if ex is None:
            ex = ThreadPoolExecutor(
                max_workers=1, thread_name_prefix=f"netns-{ns}", initializer=_enter_netns, initargs=(ns,)
            )
            self._executors[ns] = ex
        return ex

    def socket_future(
        self, ns: str, family: int = socket.AF_INET, type_: int = socket.SOCK_STREAM
    ) -> Future[socket.socket]:
        """Create a socket inside namespace ``ns`` on that namespace's worker thread."""
        return self._executor(ns).submit(socket.socket, family, type_)

    def socket_in(self, ns: str, family: int = socket.AF_INET, type_: int = socket.SOCK_STREAM) -> socket.socket:
        """Blocking form of :meth:`socket_future`."""
        return self.socket_future(ns, family, type_).result(timeout=10)

    def destroy(self) -> None:
        """Delete both namespaces (and with them the veths, qdiscs and nft tables). Idempotent."""
        for ex in self._executors.values():
            ex.shutdown(wait=True, cancel_futures=True)
        self._executors.clear()
        for ns in (self.client_ns, self.server_ns):
            if os.path.exists(os.path.join(NETNS_DIR, ns)):
                try:
                    _run(["ip", "netns", "del", ns])
                except (NetnsError, OSError, subprocess.SubprocessError) as exc:
                    log.warning("could not delete namespace %s: %s", ns, exc)
