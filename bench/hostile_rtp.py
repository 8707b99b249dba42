"""bench/hostile.py's RTP attacks (issue 35): malformed RTP, a wrong payload type, a stranger's flood, absurd `rtp`
arguments, each against a session of a netapp started with --rtp-ports, beside the good robot. What the netapp
counted is read from its /metrics (`netapp_rtp_dropped_total{reason}`, `netapp_rtp_sessions_refused_total`); UDP
datagrams the kernel dropped before the netapp read them (its socket buffer full) are counted apart."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable
from typing import Any

import requests

from netapp.rtp.packet import build
from tests.support.raw_frames_robot import RawFramesRobot
from tests.support.rtp_attacks import ABSURD_RTP_ARGS, flood, malformed, send_all

COUNTERS = ("netapp_rtp_packets_total", "netapp_rtp_dropped_total", "netapp_rtp_sessions_refused_total")


def rtp_metrics(url: str) -> dict[str, float]:
    """The RTP counters of a netapp's /metrics, by their line's name and labels."""
    rows = requests.get(f"{url}/metrics", timeout=10).text.splitlines()
    return {row.rsplit(" ", 1)[0]: float(row.rsplit(" ", 1)[1]) for row in rows if row.startswith(COUNTERS)}


def counted_since(url: str, before: dict[str, float]) -> dict[str, int]:
    now = rtp_metrics(url)
    return {key: int(value - before.get(key, 0.0)) for key, value in now.items() if value > before.get(key, 0.0)}


def summary(counts: dict[str, int], sent: int) -> tuple[int, str]:
    """(datagrams the netapp never read, a note of what it counted)."""
    read = counts.pop("netapp_rtp_packets_total", 0)
    reasons = ", ".join(f"{_label(key)} {value}" for key, value in sorted(counts.items()))
    return sent - read, f"read {read} of {sent} ({sent - read} dropped by the kernel), counted: {reasons}"


def _label(key: str) -> str:
    """'netapp_rtp_dropped_total{reason="stranger"}' -> 'stranger'."""
    return key.split("=")[-1].strip('"}')


def settle(url: str, before: dict[str, float], sent: int, timeout_s: float = 10.0) -> dict[str, int]:
    """Wait until the netapp's packet counter stops moving (it read what it will), then what it counted."""
    deadline, last = time.monotonic() + timeout_s, -1
    while time.monotonic() < deadline:
        read = counted_since(url, before).get("netapp_rtp_packets_total", 0)
        if read == last or read >= sent:
            break
        last = read
        time.sleep(0.5)  # polling the netapp's counter (UDP has no acknowledgement to wait for)
    return counted_since(url, before)


def bound_session(url: str) -> tuple[RawFramesRobot, socket.socket, tuple[str, int], int]:
    """A robot's RTP session and the socket its address is bound with (one good packet sent)."""
    robot = RawFramesRobot(url)
    rtp = robot.init(robot_id="attacker", rtp={})["rtp"]
    target = ("127.0.0.1", rtp["port"])
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    send_all(
        [build(b"\x67\x42", payload_type=96, sequence=0, timestamp=0, ssrc=rtp["ssrc"], marker=True)], target, sock
    )
    return robot, sock, target, rtp["ssrc"]


def rtp_malformed(t: Any, rounds: int = 1000) -> tuple[int, int, str]:
    """10 kinds of malformed RTP from a robot's own bound address, 1,000 rounds (10,000 datagrams)."""
    robot, sock, target, ssrc = bound_session(t.url)
    before = rtp_metrics(t.url)
    sent = sum(send_all(malformed(ssrc, base=4 * r), target, sock) for r in range(rounds))
    lost, note = summary(settle(t.url, before, sent), sent)
    sock.close()
    robot.close()
    return sent, 0, note + f"; {lost} never read"


def rtp_wrong_payload_type(t: Any, count: int = 10_000) -> tuple[int, int, str]:
    """10,000 well-formed datagrams with payload type 100 on a session that expects 96."""
    robot, sock, target, ssrc = bound_session(t.url)
    before = rtp_metrics(t.url)
    wrong = [build(b"\x65", payload_type=100, sequence=i, timestamp=i, ssrc=ssrc, marker=True) for i in range(count)]
    sent = send_all(wrong, target, sock)
    _, note = summary(settle(t.url, before, sent), sent)
    sock.close()
    robot.close()
    return sent, 0, note


def rtp_stranger_flood(t: Any, seconds: float = 10.0) -> tuple[int, int, str]:
    """A stranger floods a bound session's port with 1400-byte RTP (the session's SSRC even) for 10 s."""
    robot, sock, target, ssrc = bound_session(t.url)
    before = rtp_metrics(t.url)
    sent = flood(target, seconds, ssrc=ssrc)
    _, note = summary(settle(t.url, before, sent), sent)
    sock.close()
    robot.close()
    return sent, 0, note


def rtp_absurd_init(t: Any, rounds: int = 20) -> tuple[int, int, str]:
    """INIT on frames with absurd `rtp` arguments (a 1 MB address, 100,000 payload types, an SDP of 500 KB, ...)."""
    before = rtp_metrics(t.url)
    reasons: dict[str, int] = {}
    unanswered = 0
    for _ in range(rounds):
        for args in ABSURD_RTP_ARGS:
            robot = RawFramesRobot(t.url)
            try:
                ack = robot.init(robot_id="absurd", rtp=args)
                reasons[str(ack.get("reason"))] = reasons.get(str(ack.get("reason")), 0) + 1
            except AssertionError:  # no ack in time
                unanswered += 1
            robot.close()
    counts = counted_since(t.url, before)
    refused = sum(v for k, v in counts.items() if k.startswith("netapp_rtp_sessions_refused_total"))
    tried = rounds * len(ABSURD_RTP_ARGS)
    return tried, unanswered, f"acks {reasons}; {refused} counted as refused sessions"


RTP_ATTACKS: dict[str, Callable[[Any], tuple[int, int, str]]] = {
    "rtp-malformed": rtp_malformed,
    "rtp-wrong-payload-type": rtp_wrong_payload_type,
    "rtp-stranger-flood": rtp_stranger_flood,
    "rtp-absurd-init": rtp_absurd_init,
}
