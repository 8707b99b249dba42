"""A camera as the command line names it (`--source NAME=rtsp://...#transport=tcp`), and the FFmpeg options it is
opened with. Pure: checked at start, so a bad one is one line before anything loads."""

from __future__ import annotations

import re
from urllib.parse import parse_qs, urlsplit, urlunsplit

from netapp.server.settings import SourceSpec

NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,62}$")  # a metrics label value and a Kubernetes-friendly name
SCHEMES = ("rtsp", "rtsps")
# How the stream's RTP travels. "auto": FFmpeg's own order, UDP first, then TCP (interleaved in the RTSP connection)
# when the camera refuses UDP or no UDP packet arrives; "udp" or "tcp" only that one.
TRANSPORTS = ("auto", "udp", "tcp")
MAX_SOURCES = 16  # cameras one netapp pulls
MAX_URL_CHARS = 2048

# Low delay (docs/cameras.md#what-the-netapp-does): no input buffering, a small probe (the SDP already says what the
# stream is), 50 ms for a reordered UDP packet (FFmpeg's default is 100 ms); socket I/O times out (microseconds).
PROBE_BYTES = 65536
ANALYZE_US = 500_000
REORDER_US = 50_000
SOCKET_TIMEOUT_US = 3_000_000


def parse_source(text: str) -> SourceSpec:
    """`NAME=rtsp://host/path[#transport=udp|tcp]` -> its spec; ValueError, one line saying what to write."""
    name, sep, url = text.partition("=")
    name, url = name.strip(), url.strip()
    if not sep or not name or not url:
        raise ValueError(f"--source takes NAME=rtsp://host/path, got {text[:80]!r}")
    if not NAME.match(name):
        raise ValueError(f"--source name {name[:80]!r}: use 1 to 63 letters, digits, '.', '_' or '-'")
    if len(url) > MAX_URL_CHARS:
        raise ValueError(f"--source {name}: the URL is over {MAX_URL_CHARS} characters")
    parts = urlsplit(url)
    if parts.scheme.lower() not in SCHEMES or not parts.hostname:
        raise ValueError(f"--source {name}: give an rtsp:// or rtsps:// URL with a host, got {url[:80]!r}")
    options = parse_qs(parts.fragment)
    unknown = set(options) - {"transport"}
    if unknown:
        raise ValueError(f"--source {name}: unknown option(s) {sorted(unknown)} after '#': only transport=udp|tcp")
    transport = options.get("transport", ["auto"])[-1].lower()
    if transport not in TRANSPORTS:
        raise ValueError(f"--source {name}: #transport= takes one of {', '.join(TRANSPORTS)}, got {transport!r}")
    # The fragment is ours: never sent to the camera.
    return SourceSpec(name, urlunsplit((parts.scheme, parts.netloc, parts.path, parts.query, "")), transport)


def parse_sources(values: list[str]) -> tuple[SourceSpec, ...]:
    """Every `--source`, names unique, at most MAX_SOURCES; ValueError saying what is wrong."""
    specs = tuple(parse_source(v) for v in values)
    names = [s.name for s in specs]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f"--source names must differ: {', '.join(twice)} given twice")
    if len(specs) > MAX_SOURCES:
        raise ValueError(f"at most {MAX_SOURCES} --source cameras per netapp, got {len(specs)}: run another netapp")
    return specs


def open_options(spec: SourceSpec, libavformat_major: int = 62) -> dict[str, str]:
    """The demuxer's options for a low-delay live stream (FFmpeg's names; values are strings). FFmpeg 4
    (libavformat 58) named the socket timeout `stimeout`: its `timeout` made the RTSP demuxer listen as a server."""
    options = {
        "fflags": "nobuffer",
        "flags": "low_delay",
        "probesize": str(PROBE_BYTES),
        "analyzeduration": str(ANALYZE_US),
        "max_delay": str(REORDER_US),
        ("timeout" if libavformat_major >= 59 else "stimeout"): str(SOCKET_TIMEOUT_US),
    }
    if spec.transport != "auto":
        options["rtsp_transport"] = spec.transport
    return options
