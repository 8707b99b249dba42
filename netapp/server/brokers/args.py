"""`--publish URL` on `netapp serve`: its definition and its check, so a wrong URL stops the netapp at once with one
line (which never holds a password) rather than at its first result."""

from __future__ import annotations

import argparse

from netapp.broker.address import BrokerAddress, parse_broker_url
from netapp.broker.links import missing_client


def add_publish_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--publish",
        action="append",
        default=[],
        metavar="URL",
        help="publish every result to a broker: amqp://HOST, mqtt://HOST or kafka://HOST (repeatable); credentials "
        "from password_file= or password_env=, never on the command line; addresses and buffer in docs/broker.md",
    )


def publish_addresses(urls: list[str], netapp: str | None) -> tuple[BrokerAddress, ...]:
    """Each `--publish` URL read (ValueError, one line, for the first wrong one or one whose client library is not
    installed)."""
    addresses = tuple(parse_broker_url(url, netapp) for url in urls)
    for address in addresses:
        problem = missing_client(address.kind)
        if problem:
            raise ValueError(f"--publish {address.redacted()}: {problem}")
    return addresses
