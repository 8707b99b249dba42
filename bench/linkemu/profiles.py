"""Link profiles: pure data, figures from published measurements (sources in bench/README.md#link-profiles)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class LinkProfile:
    """One emulated access link between a robot (client) and a netapp (server).

    ``delay_ms`` is one-way and applies to both directions, so an idle round trip costs
    ``2 * delay_ms``. ``jitter_ms`` spreads each chunk's delay uniformly over
    ``delay_ms +/- jitter_ms`` (netem's default model). ``loss_pct`` is per packet and per
    direction. Rates are in Mbit/s; ``None`` means unshaped. "up" is robot -> netapp.
    """

    name: str
    delay_ms: float
    jitter_ms: float
    loss_pct: float
    rate_mbit_up: float | None
    rate_mbit_down: float | None
    description: str = ""

    def __post_init__(self) -> None:
        if self.delay_ms < 0 or self.jitter_ms < 0:
            raise ValueError("delay_ms and jitter_ms must be >= 0")
        if not 0 <= self.loss_pct < 100:
            raise ValueError("loss_pct must be in [0, 100)")
        for rate in (self.rate_mbit_up, self.rate_mbit_down):
            if rate is not None and rate <= 0:
                raise ValueError("rates must be > 0 Mbit/s or None")

    @property
    def is_passthrough(self) -> bool:
        """True when the profile emulates nothing, so no relay is needed."""
        return (
            self.delay_ms == 0
            and self.jitter_ms == 0
            and self.loss_pct == 0
            and self.rate_mbit_up is None
            and self.rate_mbit_down is None
        )

    @property
    def rtt_ms(self) -> float:
        """Idle round-trip time the profile should produce (no queueing)."""
        return 2 * self.delay_ms


LOOPBACK = LinkProfile(
    "loopback",
    0.0,
    0.0,
    0.0,
    None,
    None,
    "no emulation: the client connects straight to the server on 127.0.0.1",
)

# Gigabit LAN: line rate from IEEE 802.3ab; a switched LAN adds well under a millisecond,
# 0.1 ms one-way is our pick, not a measurement.
ETHERNET = LinkProfile(
    "ethernet",
    0.1,
    0.0,
    0.0,
    1000.0,
    1000.0,
    "switched gigabit Ethernet (nominal line rate, no loss)",
)

# Wi-Fi 6 / home-office Wi-Fi. Rates: Opensignal's US "other Wi-Fi" (home/office) averages,
# 89.6 Mbit/s down and 19.0 Mbit/s up. Delay: a Wi-Fi 6 latency study reports 99th-percentile
# latency below 10 ms with 80 MHz channels under interference; we pick 4 ms median one-way
# with +/-3 ms jitter so the tail stays inside that bound. Loss is our pick (bench/README.md#link-profiles).
WIFI = LinkProfile(
    "wifi",
    4.0,
    3.0,
    0.2,
    19.0,
    89.6,
    "Wi-Fi 6 home/office access (Opensignal averages; Wi-Fi 6 latency study)",
)

# Commercial mid-band 5G. Delay: Rohde & Schwarz one-way latency measurements on Deutsche
# Telekom's public 5G NSA network (Munich) found < 7 ms downlink at best and about 18 ms uplink
# at worst (15 Mbit/s stream); we pick 10 ms one-way with +/-4 ms jitter inside that range.
# Rates: Opensignal's US sub-6 GHz 5G averages, 112.9 Mbit/s down and 15.6 Mbit/s up.
# Loss is our pick (bench/README.md#link-profiles): RLC/HARQ retransmissions hide most radio loss.
FIVE_G = LinkProfile(
    "5g",
    10.0,
    4.0,
    0.1,
    15.6,
    112.9,
    "commercial sub-6 GHz 5G (R&S NSA one-way latency; Opensignal averages)",
)

PROFILES: dict[str, LinkProfile] = {p.name: p for p in (LOOPBACK, ETHERNET, WIFI, FIVE_G)}


def get_profile(name: str) -> LinkProfile:
    """Look a profile up by name (case-insensitive); raise KeyError listing the known names."""
    try:
        return PROFILES[name.lower()]
    except KeyError:
        raise KeyError(f"unknown link profile {name!r}; known: {', '.join(PROFILES)}") from None
