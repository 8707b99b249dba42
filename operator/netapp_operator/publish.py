"""A NetApp's brokers (docs/broker.md), `spec.publish` (every result to brokers) and `spec.consume` (robots' frames
from a broker's work queue), the same shape: checked, and rendered as the netapp's `--publish` / `--consume` flags
with each broker's password from a Secret in the environment (never in the args, which anyone who can read the
Deployment sees, nor in the URL: a URL with a password is refused). Pure functions.

    publish:
      - url: amqp://netapp@rabbitmq.messaging/      # user in the URL, password from the Secret's key `password`
        secret: rabbitmq-netapp
      - url: mqtt://mosquitto.messaging/
    consume:
      - url: kafka://kafka.messaging:9092/
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any
from urllib.parse import urlsplit

from netapp.broker.address import parse_broker_url

MAX_BROKERS = 8
PASSWORD_KEY = "password"  # the key of spec.publish[].secret (and spec.consume[].secret)
PASSWORD_ENV = "NETAPP_{field}_PASSWORD_{index}"  # where the netapp reads broker `index`'s password
PUBLISH, CONSUME = "publish", "consume"  # the spec's fields, each the netapp's flag of the same name


@dataclasses.dataclass(frozen=True)
class PublishSpec:
    url: Any
    secret: Any = None


def parse_publish(raw: Any) -> tuple[PublishSpec, ...]:
    items = raw if isinstance(raw, list) else ([] if raw is None else [raw])
    return tuple(
        PublishSpec(item.get("url"), item.get("secret")) if isinstance(item, Mapping) else PublishSpec(item)
        for item in items
    )


def publish_problems(publish: tuple[PublishSpec, ...], field: str = PUBLISH) -> list[str]:
    """What is wrong with `spec.<field>`, as sentences (a URL is quoted without its userinfo)."""
    if len(publish) > MAX_BROKERS:
        return [f"spec.{field} takes at most {MAX_BROKERS} brokers"]
    for index, broker in enumerate(publish):
        where = f"spec.{field}[{index}]"
        if not isinstance(broker.url, str) or not broker.url:
            return [f"{where}.url must be a broker URL such as amqp://user@rabbitmq/"]
        if urlsplit(broker.url).password is not None:
            return [f"{where}.url holds a password: put it in a Secret (key {PASSWORD_KEY}) named by {where}.secret"]
        try:
            parse_broker_url(_with_password(broker.url, field, index), "netapp", env={_env(field, index): "x"})
        except ValueError as exc:
            return [f"{where}.url: {exc}"]
        if broker.secret is not None and not (isinstance(broker.secret, str) and broker.secret):
            return [f"{where}.secret must name a Secret (key {PASSWORD_KEY})"]
    return []


def publish_args(publish: tuple[PublishSpec, ...], field: str = PUBLISH) -> list[str]:
    """`--publish URL` (`--consume URL`) each; a broker with a Secret reads its password from the variable
    `publish_env` sets."""
    return [
        arg
        for index, broker in enumerate(publish)
        for arg in (f"--{field}", _with_password(broker.url, field, index) if broker.secret else broker.url)
    ]


def publish_env(publish: tuple[PublishSpec, ...], field: str = PUBLISH) -> list[dict[str, Any]]:
    """Each broker's password from its Secret, as `netapp serve` reads it (`password_env=`)."""
    return [
        {"name": _env(field, index), "valueFrom": {"secretKeyRef": {"name": str(broker.secret), "key": PASSWORD_KEY}}}
        for index, broker in enumerate(publish)
        if broker.secret
    ]


def _env(field: str, index: int) -> str:
    return PASSWORD_ENV.format(field=field.upper(), index=index)


def _with_password(url: str, field: str, index: int) -> str:
    return f"{url}{'&' if '?' in url else '?'}password_env={_env(field, index)}"
