"""Checking a URL a person typed, so a missing `http://` is one clear line rather than a library's traceback."""

from __future__ import annotations

from urllib.parse import urlparse


class BadURL(ValueError):
    """A URL the robot side cannot use; the message says what to type instead."""


# Frames through a broker (docs/broker.md#frames-through-a-broker): the URL names the broker, `?netapp=` the netapp
BROKER_SCHEMES = ("amqp", "mqtt", "kafka")


def is_broker_url(url: str) -> bool:
    return urlparse(url.strip()).scheme in BROKER_SCHEMES


def netapp_url(url: str) -> str:
    """A netapp's URL as the client keeps it: a broker's as it is, an http(s) one as `http_url` checks it."""
    return url.strip() if is_broker_url(url) else http_url(url)


def http_url(url: str, what: str = "netapp") -> str:
    """`url` without a trailing slash; BadURL unless it is an http(s) URL with a host."""
    parsed = urlparse(url.strip())
    if parsed.scheme not in ("http", "https") or not parsed.hostname:
        example = url if "://" in url else f"http://{url}"
        raise BadURL(f"the {what} URL must start with http:// or https:// (got {url!r}; e.g. {example})")
    return url.strip().rstrip("/")
