"""Frames through a broker while the broker restarts (docs/broker.md#frames-through-a-broker): one `netapp serve`
(YOLOX-Nano) consuming the work queue of a real broker on loopback (Debian's RabbitMQ 3.10 or Mosquitto 2.0, started
here), one robot streaming pre-encoded 1280x720 JPEG through `NetAppClient` with a deadline; mid-stream the bench
stops the broker's process, waits `--away` seconds and starts it again on the same port (RabbitMQ with its state:
the durable queue survives). Per broker:

- first result after the return: from the broker listening again to the robot's first result;
- lost within the deadline: frames the robot put on the wire whose deadline had not passed when the broker was back
  (or that went stale before the broker stopped), with neither a result nor an error event; frames whose deadline
  fell inside the outage are counted apart (nothing could answer them in time);
- duplicates: answers (results or error events) to a frame already answered, counted where the robot's transport
  reads them (`BrokerTransport._on_reply`, wrapped here: the client itself keeps the first answer only).

    benchlock wpy -m bench.broker_restart --away 10
"""

from __future__ import annotations

import argparse
import threading
import time
from collections import Counter
from dataclasses import dataclass, field

from bench.broker_channel import SIZE, load
from bench.netapps import netapp_process
from bench.robot import jpeg_frames
from netapp.client import NetAppClient
from netapp.client.transports.broker import BrokerTransport
from netapp.framing import read_event
from tests.support.brokers import Mosquitto, RabbitMQ


@dataclass
class Tally:
    """What the robot's transport put on the wire and read back, by frame timestamp (monotonic seconds)."""

    sent: dict[int, float] = field(default_factory=dict)
    answers: Counter = field(default_factory=Counter)
    results: list[float] = field(default_factory=list)  # when each result came
    lock: threading.Lock = field(default_factory=threading.Lock)


TALLY = Tally()


def instrument() -> None:
    """Wrap the broker transport's send and read (the bench's instrument; the transport is otherwise as shipped)."""
    transmit, on_reply = BrokerTransport.transmit, BrokerTransport._on_reply

    def counted_transmit(self: BrokerTransport, frame) -> None:
        transmit(self, frame)  # raises while the connection is down: not on the wire
        with TALLY.lock:
            TALLY.sent[frame.timestamp] = time.monotonic()

    async def counted_reply(self: BrokerTransport, body: bytes) -> None:
        found = read_event(body.decode(errors="replace"))
        if found is not None and isinstance(found[1].get("data"), dict):
            timestamp = found[1]["data"].get("timestamp")
            with TALLY.lock:
                TALLY.answers[timestamp] += 1
                if found[0] == "results":
                    TALLY.results.append(time.monotonic())
        await on_reply(self, body)

    BrokerTransport.transmit, BrokerTransport._on_reply = counted_transmit, counted_reply


def run(broker, url: str, args: argparse.Namespace, frames: list[bytes]) -> dict:
    """Stream at `args.fps`; after `args.before` s the broker goes for `args.away` s; `args.after` s more."""
    global TALLY
    TALLY = Tally()
    deadline_s = args.deadline_ms / 1000
    outage: dict[str, float] = {}

    def restart() -> None:
        outage["stop"] = time.monotonic()
        broker.down()
        time.sleep(max(0.0, outage["stop"] + args.away - time.monotonic()))  # the outage itself, not a sync
        broker.start()  # returns once it listens again (polled every 50 ms)
        outage["return"] = time.monotonic()

    with netapp_process(args.model, ["--consume", url]):
        with NetAppClient(url, robot_id="restart", deadline_ms=args.deadline_ms) as client:
            restarting = threading.Timer(args.before, restart)
            restarting.start()
            start, n = time.monotonic(), 0
            while "return" not in outage or time.monotonic() < outage["return"] + args.after:
                client.send(frames[n % len(frames)])
                n += 1
                time.sleep(max(0.0, start + n / args.fps - time.monotonic()))
            restarting.join()
            time.sleep(deadline_s + 1.0)  # the last answers
    stop_at, return_at = outage["stop"], outage["return"]
    with TALLY.lock:
        sent, answers, results = dict(TALLY.sent), Counter(TALLY.answers), list(TALLY.results)
    within = [t for t, at in sent.items() if at + deadline_s <= stop_at or at + deadline_s > return_at]
    in_outage = [t for t, at in sent.items() if stop_at < at + deadline_s <= return_at]
    after = [r for r in results if r > return_at]
    return {
        "sent": len(sent),
        "answered": sum(1 for t in sent if answers[t]),
        "lost": sum(1 for t in within if not answers[t]),
        "stale_in_outage": sum(1 for t in in_outage if not answers[t]),
        "duplicates": sum(c - 1 for c in answers.values() if c > 1),
        "first_result_s": (after[0] - return_at) if after else float("nan"),
        "down_s": return_at - stop_at,
    }


def main(args: argparse.Namespace) -> None:
    instrument()
    frames = jpeg_frames(args.video, args.fps, SIZE, 50)
    print(load())
    rows = []
    for name in args.brokers:
        with RabbitMQ() if name == "rabbitmq" else Mosquitto() as broker:
            url = f"{broker.url.rstrip('/')}/?netapp=bench"
            rows.append((name, run(broker, url, args, frames)))
        print(load())
    print(
        "\n| broker | away | down (stop to listening) | frames on the wire | answered | lost within the deadline "
        "| stale in the outage | duplicates | first result after the return |\n"
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|"
    )
    for name, r in rows:
        print(
            f"| {name} | {args.away:g} s | {r['down_s']:.1f} s | {r['sent']} | {r['answered']} | {r['lost']} "
            f"| {r['stale_in_outage']} | {r['duplicates']} | {r['first_result_s']:.2f} s |"
        )


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="../shared/models/yolox_nano.onnx")
    parser.add_argument("--video", default="../shared/media/pedestrians.avi")
    parser.add_argument("--brokers", nargs="+", choices=("rabbitmq", "mosquitto"), default=["rabbitmq", "mosquitto"])
    parser.add_argument("--fps", type=float, default=10.0)
    parser.add_argument("--deadline-ms", type=float, default=1000.0)
    parser.add_argument("--before", type=float, default=5.0, help="seconds streaming before the broker stops")
    parser.add_argument("--away", type=float, default=10.0)
    parser.add_argument("--after", type=float, default=8.0, help="seconds streaming after the broker is back")
    main(parser.parse_args())
