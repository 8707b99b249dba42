"""`--publish URL` and `--consume URL` on `netapp serve`: their definitions and their check, so a wrong URL stops the
netapp at once with one line (which never holds a password) rather than at its first result or frame."""

from __future__ import annotations

import argparse

from netapp.broker.address import BrokerAddress, parse_broker_url
from netapp.broker.links import missing_client


def add_broker_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--publish",
        action="append",
        default=[],
        metavar="URL",
        help="publish every result to a broker: amqp://HOST, mqtt://HOST or kafka://HOST (repeatable); credentials "
        "from password_file= or password_env=, never on the command line; addresses and buffer in docs/broker.md",
    )
    parser.add_argument(
        "--consume",
        action="append",
        default=[],
        metavar="URL",
        help="take robots' frames from a broker's work queue and answer them there: amqp://HOST, mqtt://HOST or "
        "kafka://HOST (repeatable; docs/broker.md#frames-through-a-broker)",
    )


def publish_addresses(urls: list[str], netapp: str | None) -> tuple[BrokerAddress, ...]:
    """Each `--publish` URL read (ValueError, one line, for the first wrong one or one whose client library is not
    installed)."""
    return _addresses("--publish", urls, netapp)


def consume_addresses(urls: list[str], netapp: str | None) -> tuple[BrokerAddress, ...]:
    """Each `--consume` URL read, as `publish_addresses`."""
    return _addresses("--consume", urls, netapp)


def _addresses(flag: str, urls: list[str], netapp: str | None) -> tuple[BrokerAddress, ...]:
    addresses = tuple(parse_broker_url(url, netapp) for url in urls)
    for address in addresses:
        problem = missing_client(address.kind)
        if problem:
            raise ValueError(f"{flag} {address.redacted()}: {problem}")
    return addresses
