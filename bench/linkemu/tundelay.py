"""A packet delayer for the netns link: every IP packet that crosses the middle namespace goes through a TUN device
and waits there `delay_ms` before it goes on, so TCP and UDP see the same delay on the same lossy path (this kernel
has no netem). Run inside the middle namespace (`ip netns exec M python -m bench.linkemu.tundelay tun0 20`); its
policy routing (`bench/udp.py`, `Path`) sends what arrives on the veths to the TUN device, and what comes back out of
it is routed on as usual."""

from __future__ import annotations

import asyncio
import fcntl
import os
import struct
import sys

TUNSETIFF = 0x400454CA
IFF_TUN, IFF_NO_PI = 0x0001, 0x1000
MAX_PACKET = 65536


def open_tun(name: str) -> int:
    fd = os.open("/dev/net/tun", os.O_RDWR | os.O_NONBLOCK)
    fcntl.ioctl(fd, TUNSETIFF, struct.pack("16sH", name.encode(), IFF_TUN | IFF_NO_PI))
    return fd


async def delay(name: str, delay_ms: float) -> None:
    fd = open_tun(name)
    loop = asyncio.get_running_loop()

    def write(packet: bytes) -> None:
        try:
            os.write(fd, packet)
        except OSError:  # the stack refused it (a full queue): lost, as on a link
            pass

    def readable() -> None:
        while True:
            try:
                packet = os.read(fd, MAX_PACKET)
            except BlockingIOError:
                return
            loop.call_later(delay_ms / 1000, write, packet)

    loop.add_reader(fd, readable)
    print("ready", flush=True)
    await asyncio.Event().wait()


if __name__ == "__main__":
    asyncio.run(delay(sys.argv[1], float(sys.argv[2])))
