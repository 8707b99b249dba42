"""A camera as the command line names it (`--source NAME=rtsp://...#transport=tcp`), and the FFmpeg options it is
opened with. Pure: parsed once, strictly, at start, so a URL that could not be pulled as written (an unescaped '@',
'/', '?' or '#' in the password, a space, a port over 65535) is one line before anything loads, never a camera that
silently never comes. No message here shows the URL's user or password (`redaction`)."""

from __future__ import annotations

import re

from netapp.server.settings import SourceSpec
from netapp.server.sources.redaction import redact

NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,62}$")  # a metrics label value and a Kubernetes-friendly name
SCHEMES = ("rtsp", "rtsps")
# How the stream's RTP travels. "auto": FFmpeg's own order, UDP first, then TCP (interleaved in the RTSP connection)
# when the camera refuses UDP or no UDP packet arrives; "udp" or "tcp" only that one.
TRANSPORTS = ("auto", "udp", "tcp")
MAX_SOURCES = 16  # cameras one netapp pulls
MAX_URL_CHARS = 2048
# RFC 3986's characters: a user and password (unreserved, sub-delims, ':', %HH), a path and query (also '@', '/', '?')
_PLAIN = r"A-Za-z0-9._~\-!$&'()*+,;=:"
USERINFO = re.compile(rf"^(?:[{_PLAIN}]|%[0-9A-Fa-f]{{2}})*$")
PATH_QUERY = re.compile(rf"^(?:[{_PLAIN}@/?]|%[0-9A-Fa-f]{{2}})*$")
_LABEL = r"[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?"
HOST = re.compile(rf"^(?:{_LABEL}(?:\.{_LABEL})*\.?|\[[0-9A-Fa-f:.]+\])$")
ESCAPE_HINT = "percent-encode it in the user or password ('@' %40, '/' %2F, '?' %3F, '#' %23, a space %20)"

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
        raise ValueError(f"--source takes NAME=rtsp://host/path, got {redact(text)[:80]!r}")
    if not NAME.match(name):
        raise ValueError(f"--source name {name[:80]!r}: use 1 to 63 letters, digits, '.', '_' or '-'")
    if len(url) > MAX_URL_CHARS:
        raise ValueError(f"--source {name}: the URL is over {MAX_URL_CHARS} characters")
    url, transport = strict_url(name, url)
    return SourceSpec(name, url, transport)


def strict_url(name: str, text: str) -> tuple[str, str]:
    """A camera URL -> (what FFmpeg opens, its transport), read exactly as FFmpeg will read it; ValueError, one line
    that never shows its password, for anything FFmpeg would read otherwise or not at all."""
    where = f"--source {name}"
    if any(c.isspace() or ord(c) < 0x20 or ord(c) >= 0x7F for c in text):
        raise ValueError(f"{where}: the URL holds a space, a control or a non-ASCII character: {ESCAPE_HINT}")
    scheme, sep, rest = text.partition("://")
    if not sep or scheme.lower() not in SCHEMES:
        raise ValueError(f"{where}: give an rtsp:// or rtsps:// URL with a host, got {redact(text)[:80]!r}")
    rest, _, fragment = rest.partition("#")
    cut = next((i for i, c in enumerate(rest) if c in "/?"), len(rest))
    authority, path_query = rest[:cut], rest[cut:]
    if "@" in path_query or "@" in fragment:
        raise ValueError(f"{where}: an '@' after the host: is a '/', '?' or '#' in the password? {ESCAPE_HINT}")
    userinfo, at, hostport = authority.rpartition("@")
    if "@" in userinfo:
        raise ValueError(f"{where}: two '@' in the URL: {ESCAPE_HINT}")
    if at and not USERINFO.match(userinfo):
        raise ValueError(f"{where}: the user or password holds a character a URL cannot carry as is: {ESCAPE_HINT}")
    host, port = hostport, ""
    if hostport.startswith("["):
        host, bracket, after = hostport.partition("]")
        host, port = host + bracket, after.removeprefix(":")
        if after and not after.startswith(":"):
            raise ValueError(f"{where}: after an [IPv6] host only :PORT may follow")
    elif ":" in hostport:
        host, _, port = hostport.partition(":")
    if not host or not HOST.match(host):
        raise ValueError(f"{where}: give an rtsp:// or rtsps:// URL with a host, got {host[:80]!r} as its host")
    if port and not (port.isdigit() and 1 <= int(port) <= 65535):
        raise ValueError(f"{where}: the port must be a number from 1 to 65535, got {port[:12]!r}")
    if not PATH_QUERY.match(path_query):
        raise ValueError(f"{where}: the path holds a character a URL cannot carry as is: percent-encode it")
    return f"{scheme}://{authority}{path_query}", our_transport(where, fragment)  # the fragment is ours


def our_transport(where: str, fragment: str) -> str:
    """`transport=udp|tcp` after the URL's '#' (never sent to the camera) -> the transport; ValueError otherwise."""
    if not fragment:
        return "auto"
    key, eq, value = fragment.partition("=")
    if key != "transport":
        raise ValueError(f"{where}: unknown option(s) [{key[:20]!r}] after '#': only transport=udp|tcp")
    transport = value.lower()
    if not eq or transport not in TRANSPORTS:
        raise ValueError(f"{where}: #transport= takes one of {', '.join(TRANSPORTS)}, got {value[:20]!r}")
    return transport


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


def open_options(spec: SourceSpec, libavformat_major: int = 62, max_pixels: int | None = None) -> dict[str, str]:
    """The demuxer's options for a low-delay live stream (FFmpeg's names; values are strings). FFmpeg 4
    (libavformat 58) named the socket timeout `stimeout`: its `timeout` made the RTSP demuxer listen as a server.
    `max_pixels` goes to the decoders the stream's probe opens: without it, a size the SDP or an SPS claims
    (16000x16000) is decoded at, gigabytes, before the netapp could read the size and refuse it."""
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
    if max_pixels is not None:
        options["max_pixels"] = str(max_pixels)
    return options
