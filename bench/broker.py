"""The broker channel's publisher (docs/broker.md), against real brokers on loopback started here (RabbitMQ, Mosquitto;
Kafka is librdkafka's mock cluster, a test double, unless KAFKA_BOOTSTRAP is set), side by side in one run:

- throughput: results a publisher gets confirmed per second, per broker (a YOLOX-Nano result of 10 detections,
  wrapped as netapp.broker.message makes it: 1.26 KB);
- away: the broker (Mosquitto) stopped for `--away` seconds while results keep coming at `--rate` a second: the
  process's memory (RSS) every second, the buffer's bound, what overflowed by reason, and the time from the broker's
  return to the buffer drained.

    python -m bench.broker                     # both parts (about a minute)
    python -m bench.broker --part away --away 30 --rate 100 --buffer 1000

Prints a markdown table with the load average beside it (take `flock /tmp/heavy.lock` around a run on a shared box).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import time

import psutil

from netapp.broker.address import parse_broker_url
from netapp.broker.message import ModelIdentity, encode, result_message
from netapp.broker.publisher import Publisher, PublisherEvents
from tests.support.brokers import KafkaMock, Mosquitto, RabbitMQ, kafka_bootstrap


def sample_body(n: int) -> bytes:
    detections = [
        {"bbox": [10.0 + i, 20.0, 110.0 + i, 220.0], "score": 0.8123, "class": 0, "class_name": "person"}
        for i in range(10)
    ]
    result = {
        "timestamp": time.time_ns(),
        "recv_timestamp": n,
        "timestamp_before_process": n + 1_000_000,
        "timestamp_after_process": n + 20_000_000,
        "send_timestamp": n + 21_000_000,
        "detections": detections,
        "dropped": 0,
        "hint": {"input_size": [416, 416], "next_frame_in_ms": 12.5},
    }
    return encode(result_message(result, netapp="bench", source="robot-1", session_id="s", model=ModelIdentity("m")))


def load() -> str:
    return "load average " + ", ".join(f"{x:.2f}" for x in os.getloadavg())


async def throughput(url: str, count: int) -> float:
    """Results per second confirmed by the broker at `url`, `count` offered at once."""
    publisher = Publisher(parse_broker_url(url, "bench"))
    publisher.start()
    while not publisher.connected:
        await asyncio.sleep(0.01)
    body = sample_body(0)
    began = time.perf_counter()
    for _ in range(count):
        topic, key = publisher.address.destination("robot-1")
        publisher.offer(topic, body, key=key)
    while publisher.published < count:
        await asyncio.sleep(0.001)
    rate = count / (time.perf_counter() - began)
    await publisher.close()
    return rate


async def away(away_s: float, rate: float, buffer: int) -> dict:
    """Mosquitto down for `away_s` mid-stream while results come at `rate`/s into a buffer of `buffer`."""
    process = psutil.Process()
    dropped: dict[str, int] = {}
    with Mosquitto() as broker:
        address = parse_broker_url(f"mqtt://127.0.0.1:{broker.port}/?buffer={buffer}", "bench")
        events = PublisherEvents(dropped=lambda reason: dropped.__setitem__(reason, dropped.get(reason, 0) + 1))
        publisher = Publisher(address, events=events)
        publisher.start()
        topic, _ = address.destination("robot-1")
        body = sample_body(0)
        rss_before = process.memory_info().rss
        peak_rss, peak_bytes, offered = rss_before, 0, 0
        start = time.monotonic()
        await asyncio.to_thread(broker.down)
        while time.monotonic() - start < away_s:
            offered += 1
            publisher.offer(topic, body)
            peak_bytes = max(peak_bytes, publisher.backlog.bytes)
            if offered % int(rate) == 0:
                peak_rss = max(peak_rss, process.memory_info().rss)
            await asyncio.sleep(1 / rate)
        published_before = publisher.published
        await asyncio.to_thread(broker.start)
        back = time.monotonic()
        while len(publisher.backlog):
            await asyncio.sleep(0.005)
        drained_s = time.monotonic() - back
        sent = publisher.published - published_before
        await publisher.close()
    return {
        "offered": offered,
        "buffer": buffer,
        "buffer_bytes_peak": peak_bytes,
        "rss_growth_mb": (peak_rss - rss_before) / 2**20,
        "dropped": dropped,
        "sent_after": sent,
        "drained_s": drained_s,
    }


async def main(args: argparse.Namespace) -> None:
    print(load())
    if args.part in ("all", "throughput"):
        rows = []
        with RabbitMQ() as rabbit, Mosquitto() as mosquitto:
            kafka = KafkaMock() if not kafka_bootstrap() else None
            urls = {
                "RabbitMQ 3.10 (confirms)": rabbit.url,
                "Mosquitto 2.0 (QoS 1)": mosquitto.url,
                ("Kafka (KAFKA_BOOTSTRAP)" if kafka is None else "librdkafka mock (acks=all, idempotent)"): (
                    f"kafka://{kafka_bootstrap()}/" if kafka is None else kafka.url
                ),
            }
            for name, url in urls.items():
                rows.append((name, await throughput(url, args.count)))
            if kafka is not None:
                kafka.stop()
        print(f"\n| broker | results confirmed per second ({args.count} offered at once, 1.26 KB each) |\n|---|---:|")
        for name, rate in rows:
            print(f"| {name} | {rate:,.0f} |")
        print(load())
    if args.part in ("all", "away"):
        found = await away(args.away, args.rate, args.buffer)
        print(
            f"\n| Mosquitto away | offered | buffer bound | buffer peak | RSS growth | overflow by reason | sent on "
            f"return | drained in |\n|---|---:|---:|---:|---:|---|---:|---:|\n"
            f"| {args.away:g} s at {args.rate:g}/s | {found['offered']} | {found['buffer']} results | "
            f"{found['buffer_bytes_peak'] / 2**20:.2f} MiB | {found['rss_growth_mb']:.1f} MiB | {found['dropped']} | "
            f"{found['sent_after']} | {found['drained_s']:.2f} s |"
        )
        print(load())


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=("all", "throughput", "away"), default="all")
    parser.add_argument("--count", type=int, default=5000)
    parser.add_argument("--away", type=float, default=30.0)
    parser.add_argument("--rate", type=float, default=100.0, help="results a second while the broker is away")
    parser.add_argument("--buffer", type=int, default=1000)
    asyncio.run(main(parser.parse_args()))
