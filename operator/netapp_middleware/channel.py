"""An app whose robots send their frames through a broker (docs/broker.md#from-the-middleware): its catalogue entry's
`channel`. Pure.

    channel:
      broker: kafka://kafka.messaging:9092/      # the netapp takes its frames here: its spec.consume
      secret: kafka-netapp                       # optional: the netapp's password (Secret key `password`)
      robotUrl: kafka://robot@kafka.messaging:9092/?password_env=ROBOT_BROKER_PASSWORD   # optional

The middleware renders `spec.consume` with the NetApp's name (`netapp=`), and hands each robot, as its deployment's
`url`, `robotUrl` (by default `broker` without its user) with `netapp=<the NetApp>`: what `NetAppClient` and `netapp
stream` take as they are. Never a password: neither URL may hold one. The netapp's comes from the Secret (a cluster's;
the local backend refuses it); a robot's own, where the broker wants one, is the robot's, given to it out of band,
and `robotUrl` names where the robot finds it (`password_env=` a variable, `password_file=` a file, on the robot).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qsl, urlencode, urlsplit, urlunsplit

from netapp.broker.address import CREDENTIAL_OPTIONS, parse_broker_url

KEYS = ("broker", "secret", "robotUrl")


@dataclass(frozen=True)
class BrokerChannel:
    broker: str  # the netapp's --consume URL (its netapp= added per NetApp)
    robot_url: str  # what a robot is given (its netapp= added per NetApp)
    secret: str | None = None

    def public(self) -> dict[str, Any]:
        return {"broker": self.broker, "robotUrl": self.robot_url, "secret": self.secret}

    def consume(self, netapp: str) -> dict[str, Any]:
        """The NetApp's `spec.consume` entry."""
        return {"url": with_netapp(self.broker, netapp), **({"secret": self.secret} if self.secret else {})}


def with_netapp(url: str, netapp: str) -> str:
    """`url` naming the netapp `netapp` (its `netapp=` option)."""
    parts = urlsplit(url)
    query = [(k, v) for k, v in parse_qsl(parts.query, keep_blank_values=True) if k != "netapp"]
    return urlunsplit(parts._replace(path=parts.path or "/", query=urlencode([*query, ("netapp", netapp)])))


def parse_channel(raw: Any, app: str) -> BrokerChannel | None:
    """A catalogue entry's `channel` (None: the netapp's own URL); ValueError, one line naming the app, never quoting
    a password."""
    if raw is None:
        return None
    where = f"app {app!r}: channel"
    if not isinstance(raw, Mapping) or set(raw) - set(KEYS) or not isinstance(raw.get("broker"), str):
        raise ValueError(f"{where} is {{broker: URL, secret?: NAME, robotUrl?: URL}}")
    broker = _checked(raw["broker"], f"{where}.broker", robot=False)
    secret = raw.get("secret")
    if secret is not None and not (isinstance(secret, str) and secret):
        raise ValueError(f"{where}.secret must name a Secret (key password)")
    robot_url = raw.get("robotUrl")
    if robot_url is None:
        parts = urlsplit(broker)
        robot_url = urlunsplit(parts._replace(netloc=parts.netloc.rpartition("@")[2]))  # the netapp's user is not
        # the robot's
    elif not isinstance(robot_url, str):
        raise ValueError(f"{where}.robotUrl must be a broker URL")
    robot_url = _checked(robot_url, f"{where}.robotUrl", robot=True)
    if urlsplit(robot_url).scheme != urlsplit(broker).scheme:
        raise ValueError(f"{where}.robotUrl must speak what broker does ({urlsplit(broker).scheme}://)")
    return BrokerChannel(broker, robot_url, secret)


def _checked(url: str, where: str, *, robot: bool) -> str:
    """`url` if it is a broker URL without a password or a netapp= (the middleware names the netapp); a robot's may
    name where the robot finds its credentials, which are not looked for here."""
    parts = urlsplit(url.strip())
    if parts.password is not None:
        raise ValueError(f"{where} holds a password: the netapp's comes from secret, a robot's from the robot")
    options = dict(parse_qsl(parts.query, keep_blank_values=True))
    if "netapp" in options:
        raise ValueError(f"{where}: no netapp= (the middleware names each NetApp)")
    credentials = set(options) & set(CREDENTIAL_OPTIONS)
    if credentials and not robot:
        raise ValueError(f"{where}: the netapp's password comes from secret, not {', '.join(sorted(credentials))}")
    bare = urlencode([(k, v) for k, v in options.items() if k not in CREDENTIAL_OPTIONS])
    try:
        parse_broker_url(urlunsplit(parts._replace(query=bare)), "netapp", env={})
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    return url.strip()
