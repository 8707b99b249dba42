"""A broker URL, read once (pure but for the credential files and variables it names): where the broker is, who to
log in as, and where each source's results go.

    amqp://HOST[:5672][/VHOST]?exchange=netapp&routing_key=results.{netapp}.{source}
    mqtt://HOST[:1883]?topic=netapp/{netapp}/{source}/results&available=netapp/{netapp}/available
    kafka://HOST[:9092][,HOST2:PORT...]?topic=netapp.results&key={netapp}/{source}
    (frames through a broker: frames=, the work queue, and replies=, where a robot's answers go; DEFAULT_ADDRESSING)

Credentials never need to be on a command line: `username_file=`/`password_file=` read a file (a mounted Secret),
`username_env=`/`password_env=` a variable; `user:password@` in the URL works too. However they came, `redacted()` is
what any log line, metric label or page shows (the user at most, never the password), and errors here quote only
that. `buffer=` (results) and `buffer_mb=` bound what waits while the broker is away; `prefetch=` the frames a netapp
holds from its work queue; `netapp=` names the netapp a robot sends its frames to (a netapp's own is NETAPP_ID).
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from string import Formatter
from urllib.parse import parse_qsl, unquote, urlsplit

AMQP, MQTT, KAFKA = "amqp", "mqtt", "kafka"
DEFAULT_PORTS = {AMQP: 5672, MQTT: 1883, KAFKA: 9092}
DEFAULT_NETAPP = "netapp"  # when NETAPP_ID is not set (the operator and the local backend set it)

# Where a result goes by default, per broker (docs/broker.md#addresses); {netapp} and {source} are filled per result.
# Frames through a broker (docs/broker.md#frames-through-a-broker): `frames` is the netapp's work queue (AMQP queue,
# MQTT topic under a shared subscription, Kafka topic under a consumer group), `replies` where a robot's results go
# ({source}: the robot's session), `dead_letter` the exchange a frame that cannot be decoded is dead-lettered to.
DEFAULT_ADDRESSING = {
    AMQP: {
        "exchange": "netapp",
        "routing_key": "results.{netapp}.{source}",
        "frames": "netapp.frames.{netapp}",
        "dead_letter": "netapp.dead",
    },
    MQTT: {
        "topic": "netapp/{netapp}/{source}/results",
        "available": "netapp/{netapp}/available",
        "frames": "netapp/{netapp}/frames",
        "replies": "netapp/{netapp}/replies/{source}",
    },
    KAFKA: {
        "topic": "netapp.results",
        "key": "{netapp}/{source}",
        "frames": "netapp.frames.{netapp}",
        "replies": "netapp.replies",
    },
}
TEMPLATE_FIELDS = frozenset({"netapp", "source"})
CREDENTIAL_OPTIONS = ("username_file", "username_env", "password_file", "password_env")
DEFAULT_BUFFER = 10_000  # results waiting while the broker is away
DEFAULT_BUFFER_MB = 64.0
DEFAULT_PREFETCH = 16  # frames a netapp holds unacknowledged from a work queue: enough to keep it busy, never a hoard
MAX_NAME = 128  # a source's part of a topic or key
_UNSAFE = re.compile(r"[^A-Za-z0-9_-]")  # topic separators (. /) and wildcards (+ # *) become "_"


@dataclass(frozen=True)
class BrokerAddress:
    """One broker, as a publisher needs it. `password` is left out of repr and of `redacted()`."""

    kind: str  # AMQP, MQTT or KAFKA
    hosts: tuple[tuple[str, int], ...]
    netapp: str  # this netapp's name: {netapp} in the addressing
    addressing: Mapping[str, str]  # exchange / routing_key, topic / available, topic / key: as DEFAULT_ADDRESSING
    vhost: str = "/"  # AMQP's virtual host
    username: str | None = None
    password: str | None = field(default=None, repr=False)
    buffer: int = DEFAULT_BUFFER
    buffer_bytes: int = int(DEFAULT_BUFFER_MB * 2**20)
    prefetch: int = DEFAULT_PREFETCH

    def redacted(self) -> str:
        """The URL as anything may show it: scheme, user, hosts and vhost; never the password nor the query."""
        user = f"{self.username}@" if self.username else ""
        hosts = ",".join(f"{h}:{p}" if ":" not in h else f"[{h}]:{p}" for h, p in self.hosts)
        path = f"/{self.vhost.lstrip('/')}" if self.kind == AMQP and self.vhost != "/" else "/"
        return f"{self.kind}://{user}{hosts}{path}"

    def fill(self, name: str, source: str) -> str:
        """The addressing entry `name` (e.g. "routing_key") for `source`'s results."""
        return self.addressing[name].format(netapp=self.netapp, source=topic_part(source))

    def destination(self, source: str) -> tuple[str, str | None]:
        """Where `source`'s results go: (AMQP routing key, None), (MQTT topic, None) or (Kafka topic, its key)."""
        if self.kind == AMQP:
            return self.fill("routing_key", source), None
        if self.kind == MQTT:
            return self.fill("topic", source), None
        return self.fill("topic", source), self.fill("key", source)


def topic_part(name: str) -> str:
    """`name` as one level of a topic or routing key: separators and wildcards replaced, bounded, never empty."""
    return _UNSAFE.sub("_", name)[:MAX_NAME] or "_"


def parse_broker_url(url: str, netapp: str | None = None, env: Mapping[str, str] | None = None) -> BrokerAddress:
    """`url` read into a BrokerAddress; ValueError, one line that never holds the password, for anything wrong.
    `netapp`: this netapp's name (default $NETAPP_ID, else "netapp"); `env`: where *_env credentials are read."""
    env = os.environ if env is None else env
    parts = urlsplit(url.strip())
    kind = parts.scheme.lower()
    shown = f"{kind}://{parts.hostname or ''}/..."  # what an error may quote: never the userinfo nor the query
    if kind not in DEFAULT_PORTS:
        raise ValueError(f"a broker URL starts amqp://, mqtt:// or kafka://, got {kind or 'none'}:// ({shown})")
    hosts = _hosts(parts.netloc.rpartition("@")[2], DEFAULT_PORTS[kind], shown)
    if kind != KAFKA and len(hosts) > 1:
        raise ValueError(f"{shown}: one host for {kind}:// (Kafka alone takes a list of bootstrap servers)")
    options = dict(parse_qsl(parts.query, keep_blank_values=True))
    addressing = dict(DEFAULT_ADDRESSING[kind])
    known = set(addressing) | set(CREDENTIAL_OPTIONS) | {"buffer", "buffer_mb", "prefetch", "netapp"}
    unknown = sorted(set(options) - known)
    if unknown:
        raise ValueError(f"{shown}: unknown option {', '.join(unknown)} (known: {', '.join(sorted(known))})")
    for name in addressing:
        if name in options:
            addressing[name] = _template(options[name], name, shown)
    username = _credential(options, "username", unquote(parts.username) if parts.username else None, env, shown)
    password = _credential(options, "password", unquote(parts.password) if parts.password else None, env, shown)
    vhost = unquote(parts.path[1:]) if kind == AMQP and len(parts.path) > 1 else "/"
    return BrokerAddress(
        kind=kind,
        hosts=hosts,
        netapp=topic_part(options.get("netapp") or netapp or env.get("NETAPP_ID") or DEFAULT_NETAPP),
        addressing=addressing,
        vhost=vhost,
        username=username,
        password=password,
        buffer=_number(options, "buffer", DEFAULT_BUFFER, int, shown),
        buffer_bytes=int(_number(options, "buffer_mb", DEFAULT_BUFFER_MB, float, shown) * 2**20),
        prefetch=_number(options, "prefetch", DEFAULT_PREFETCH, int, shown),
    )


def _hosts(netloc: str, default_port: int, shown: str) -> tuple[tuple[str, int], ...]:
    hosts = []
    for item in netloc.split(","):
        host, port = item, default_port
        if item.startswith("["):  # [IPv6]:port
            host, _, rest = item[1:].partition("]")
            port_text = rest[1:] if rest.startswith(":") else ""
        else:
            host, _, port_text = item.partition(":")
        if port_text:
            if not port_text.isdigit() or not 0 < int(port_text) < 65536:
                raise ValueError(f"{shown}: bad port {port_text!r}")
            port = int(port_text)
        if not host:
            raise ValueError(f"{shown}: a broker URL needs a host")
        hosts.append((host, port))
    return tuple(hosts)


def _template(text: str, name: str, shown: str) -> str:
    fields = {f for _, f, _, _ in Formatter().parse(text) if f is not None}
    if not text or fields - TEMPLATE_FIELDS:
        raise ValueError(f"{shown}: {name}={text!r} may use only {{netapp}} and {{source}}")
    return text


def _credential(options: dict[str, str], what: str, inline: str | None, env: Mapping[str, str], shown: str):
    """A user name or password from exactly one of the URL, `WHAT_file=PATH` or `WHAT_env=VAR`."""
    path, variable = options.get(f"{what}_file"), options.get(f"{what}_env")
    given = [x for x in (inline, path, variable) if x is not None]
    if len(given) > 1:
        raise ValueError(f"{shown}: give the {what} one way (in the URL, {what}_file= or {what}_env=)")
    if path is not None:
        try:
            return Path(path).read_text().strip()
        except OSError as exc:
            raise ValueError(f"{shown}: cannot read {what}_file {path}: {exc.strerror}") from None
    if variable is not None:
        if variable not in env:
            raise ValueError(f"{shown}: {what}_env names ${variable}, which is not set")
        return env[variable]
    return inline


def _number(options: dict[str, str], name: str, default, kind, shown: str):
    if name not in options:
        return default
    try:
        value = kind(options[name])
    except ValueError:
        value = 0
    if not value > 0:
        raise ValueError(f"{shown}: {name} must be a number above 0, got {options[name]!r}")
    return value
