"""Link emulation for the netapp benchmarks: loopback, Ethernet, Wi-Fi and 5G profiles.

Usage (a benchmark run as ``python -m bench.NAME`` from the repository root)::

    from bench.linkemu import emulated_link, PROFILES
    with emulated_link(PROFILES["5g"], target=("127.0.0.1", server_port)) as (host, port):
        ...  # connect the client to host:port
"""

from .emulator import LinkEmulator, emulated_link
from .netns import detect_capabilities, list_namespaces
from .profiles import PROFILES, LinkProfile, get_profile
from .schedule import Change, LinkSchedule, LinkState, Outages, parse_change, parse_outages, parse_trace, read_trace

__all__ = [
    "PROFILES",
    "Change",
    "LinkEmulator",
    "LinkProfile",
    "LinkSchedule",
    "LinkState",
    "Outages",
    "detect_capabilities",
    "emulated_link",
    "get_profile",
    "list_namespaces",
    "parse_change",
    "parse_outages",
    "parse_trace",
    "read_trace",
]
