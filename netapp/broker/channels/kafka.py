"""Frames through Kafka, with confluent-kafka (librdkafka): the netapp's replicas are one consumer group, named after
the netapp, on the topic `netapp.frames.<netapp>` (Kafka spreads its partitions over them); each frame is keyed by
its robot's id, so a robot's frames stay in order on one partition and reach one replica (where the newest wins).
Its envelope travels as headers (`robot_id`, `session`, `expires_ns`, `reply_to`, `correlation_id`); the answer goes
to the topic `reply_to` names (default `netapp.replies`) keyed by the robot's id, with the robot's session in a
header, and each robot reads that topic from where it stood when it connected, keeping only its own session's.

Bounded on the netapp's side (never a hoard): at most `prefetch=` frames handed over and not yet answered, and
librdkafka's own fetch queue bounded in count and bytes (`consumer_config`). A message is settled (answered, stale,
superseded or poison) by storing its offset, committed every second: a frame that cannot be decoded is skipped and
counted, never redelivered. The offset committed for a partition never passes a frame that is still being answered
(`Pending`), so a replica that dies leaves nothing unanswered behind it: the group's next owner reads it again, or
drops it as stale.

librdkafka's clients are thread-based: each poll runs on a worker thread, never on the event loop; their own log
lines go through this module's logger (never to stderr as they are)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor

from confluent_kafka import Consumer, KafkaError, KafkaException, Message, Producer, TopicPartition

from netapp.broker.address import BrokerAddress
from netapp.broker.channel import Incoming
from netapp.broker.frames import REPLY_HEADER, SESSION_HEADER, Envelope, read_envelope
from netapp.broker.link import CONNECT_TIMEOUT_S
from netapp.broker.links.kafka import DELIVERY_TIMEOUT_S, client_config, producer_config
from netapp.framing import WireError

log = logging.getLogger(__name__)

CORRELATION_HEADER = "correlation_id"
POLL_S = 0.1  # each poll's wait on its worker thread: how soon a close is noticed
FETCH_WAIT_MS = 100  # a fetch's longest wait at the broker for a frame (a real Kafka answers as soon as one comes)
QUEUED_KB = 8 * 1024
FETCH_QUEUE_BACKOFF_MS = 5  # librdkafka's fetched-ahead queue, per consumer, in KiB
FETCH_MAX_BYTES = 16 * 2**20  # one fetch response; a single message over it stalls its partition: keep the
# topic's max.message.bytes (1 MiB by default) below it
SESSION_TIMEOUT_MS = 10_000  # a replica that died gives up its partitions within this


def consumer_config(address: BrokerAddress) -> dict[str, object]:
    """The netapp's consumer (pure): group `<netapp>`, offsets stored only once settled, bounded fetching."""
    return {
        **client_config(address),
        "group.id": address.netapp,
        "enable.auto.commit": True,
        "auto.commit.interval.ms": 1000,
        "enable.auto.offset.store": False,  # `Pending` stores each offset once its frame is settled
        "auto.offset.reset": "earliest",  # a new group reads the backlog: its stale frames are dropped and counted
        "allow.auto.create.topics": True,
        "session.timeout.ms": SESSION_TIMEOUT_MS,
        "queued.min.messages": address.prefetch,  # fetched ahead: the prefetch, as on the other brokers
        "queued.max.messages.kbytes": QUEUED_KB,
        # once that queue is full, the next fetch waits this long (librdkafka's default, 1 s, would hold a partition
        # to one prefetch a second)
        "fetch.queue.backoff.ms": FETCH_QUEUE_BACKOFF_MS,
        "fetch.max.bytes": FETCH_MAX_BYTES,
        "receive.message.max.bytes": FETCH_MAX_BYTES + 512,
        "fetch.wait.max.ms": FETCH_WAIT_MS,
    }


def reply_consumer_config(address: BrokerAddress, session: str) -> dict[str, object]:
    """A robot's reader of its replies (pure): partitions assigned by hand, nothing committed."""
    return {
        **client_config(address),
        "group.id": f"netapp-robot-{session}",  # never joined (assigned by hand): librdkafka wants one all the same
        "enable.auto.commit": False,
        "allow.auto.create.topics": True,
        "queued.max.messages.kbytes": QUEUED_KB,
        "fetch.max.bytes": FETCH_MAX_BYTES,
        "receive.message.max.bytes": FETCH_MAX_BYTES + 512,
        "fetch.wait.max.ms": FETCH_WAIT_MS,
    }


class Pending:
    """The offsets handed over and not yet settled, per partition (pure): what may be committed is the oldest still
    being answered, or past the newest handed over once none is."""

    def __init__(self) -> None:
        self._open: dict[int, set[int]] = {}
        self._next: dict[int, int] = {}

    def taken(self, partition: int, offset: int) -> None:
        self._open.setdefault(partition, set()).add(offset)
        self._next[partition] = max(self._next.get(partition, 0), offset + 1)

    def settled(self, partition: int, offset: int) -> int | None:
        """The offset to commit for `partition` now that `offset` is settled; None when it was settled before."""
        taken = self._open.get(partition)
        if not taken or offset not in taken:
            return None
        taken.discard(offset)
        return min(taken) if taken else self._next[partition]


class KafkaFrames:
    spreads_robots = False  # keyed by robot: each robot's frames on one partition, so at one replica

    def __init__(self, address: BrokerAddress) -> None:
        self.address = address
        self.topic = address.fill("frames", "")
        self._producer: Producer | None = None
        self._consumer: Consumer | None = None
        self._begin()

    def _begin(self) -> None:
        """A connection's own state, new for each connect(): the robot's transport connects the same channel again
        after close() (a broker that came back)."""
        self._readers: list[asyncio.Task] = []
        self._pending = Pending()
        self._slots = asyncio.Semaphore(self.address.prefetch)
        self._lost = asyncio.Event()
        self._closed = False
        # its two pollers (the producer's, the consumer's) on threads of their own: blocking up to POLL_S each, they
        # would otherwise hold two of the event loop's default workers for good
        self._pollers = ThreadPoolExecutor(2, thread_name_prefix="netapp-kafka")

    def _poll(self, client: Producer | Consumer):
        return self._loop.run_in_executor(self._pollers, client.poll, POLL_S)

    def _on_error(self, error: KafkaError) -> None:  # on a polling thread
        if error.fatal() or error.code() == KafkaError._ALL_BROKERS_DOWN:
            self._loop.call_soon_threadsafe(self._lost.set)

    async def connect(self) -> None:
        self._loop = asyncio.get_running_loop()
        if self._closed:
            self._begin()
        producer = Producer({**producer_config(self.address), "error_cb": self._on_error, "logger": log})
        # librdkafka connects lazily: asking for the cluster's metadata proves the broker is there
        await asyncio.to_thread(producer.list_topics, timeout=CONNECT_TIMEOUT_S)
        self._producer = producer
        self._readers.append(self._loop.create_task(self._serve_producer()))

    async def _serve_producer(self) -> None:
        """librdkafka's delivery reports and errors come from polls: one on a worker thread at a time."""
        while not self._closed:
            await self._poll(self._producer)

    async def _produce(self, topic: str, body: bytes, key: str, headers: dict[str, str]) -> None:
        """`body` to `topic`; returns once every in-sync replica has it (raises otherwise)."""
        done = self._loop.create_future()

        def delivered(error, _message) -> None:  # on the producer's polling thread
            outcome = KafkaException(error) if error is not None else None
            self._loop.call_soon_threadsafe(_resolve, done, outcome)

        self._producer.produce(topic, body, key=key, headers=list(headers.items()), on_delivery=delivered)
        await asyncio.wait_for(done, DELIVERY_TIMEOUT_S + 1.0)

    # -- the netapp's end -----------------------------------------------------------------------------------------

    async def consume(self, handler: Callable[[Incoming], Awaitable[None]]) -> None:
        consumer = Consumer({**consumer_config(self.address), "error_cb": self._on_error, "logger": log})
        # asked for by name, the topic is made where the broker makes topics (auto.create.topics.enable): a group
        # subscribed to a topic that is not there yet would wait for its next metadata refresh, minutes away
        await asyncio.to_thread(consumer.list_topics, self.topic, timeout=CONNECT_TIMEOUT_S)
        consumer.subscribe([self.topic])
        self._consumer = consumer
        self._readers.append(self._loop.create_task(self._read(consumer, handler)))

    async def _read(self, consumer: Consumer, handler: Callable[[Incoming], Awaitable[None]]) -> None:
        while not self._closed:
            await self._slots.acquire()  # released once the frame is settled: at most `prefetch` handed over
            message = await self._poll(consumer)
            if message is None or message.error() is not None:
                self._slots.release()
                if message is not None and message.error().fatal():
                    self._lost.set()
                continue
            self._pending.taken(message.partition(), message.offset())
            incoming = self._incoming(consumer, message)
            try:
                await handler(incoming)
            except Exception:  # noqa: BLE001 (one frame's failure, e.g. an answer the broker refused, ends nothing)
                log.warning("a Kafka frame could not be handled; skipped", exc_info=True)
                await incoming.ack()

    def _incoming(self, consumer: Consumer, message: Message) -> Incoming:
        headers = _headers(message)
        try:
            envelope, problem = self._envelope(headers), None
        except WireError as exc:
            envelope, problem = None, str(exc)
        settled = False

        async def settle() -> None:  # the same either way: Kafka has no dead letters, what is settled is skipped
            nonlocal settled
            if settled:
                return
            settled = True
            self._slots.release()
            offset = self._pending.settled(message.partition(), message.offset())
            if offset is not None:
                with contextlib.suppress(KafkaException):  # the partition went to another replica meanwhile
                    consumer.store_offsets(offsets=[TopicPartition(message.topic(), message.partition(), offset)])

        correlation = _text(headers.get(CORRELATION_HEADER))
        return Incoming(message.value() or b"", envelope, problem, correlation, settle, settle)

    def _envelope(self, headers: dict[str, bytes | None]) -> Envelope:
        """The frame's envelope; its reply address must be this netapp's replies topic for the robot's session
        (`replies=`, the same on both ends): the netapp writes to no topic a robot names (a topic that does not
        exist would hold each answer for the delivery timeout, an internal one is not a robot's)."""
        envelope = read_envelope(headers, _text(headers.get(REPLY_HEADER)))
        expected = self.address.fill("replies", envelope.session)
        if envelope.reply != expected:
            shown = str(envelope.reply)[:64]
            raise WireError("bad_envelope", f"{REPLY_HEADER} must be {expected} (replies=), got {shown!r}")
        return envelope

    async def reply(self, envelope: Envelope, correlation: str | None, body: bytes) -> None:
        headers = {SESSION_HEADER: envelope.session}
        if correlation:
            headers[CORRELATION_HEADER] = correlation
        try:
            await self._produce(envelope.reply, body, envelope.robot, headers)
        except Exception:
            # no redelivery in Kafka but from the last commit: the intake connects again, and the group's new
            # member reads what is not settled (this frame among it) again, or drops it as stale
            self._lost.set()
            raise

    # -- the robot's end ------------------------------------------------------------------------------------------

    async def open_replies(self, session: str, handler: Callable[[bytes], Awaitable[None]]) -> str:
        """Read the reply topic from its end now (every partition's high watermark, so no reply sent after this
        returns is missed), keeping this session's replies."""
        topic = self.address.fill("replies", session)
        consumer = Consumer({**reply_consumer_config(self.address, session), "logger": log})

        def assign() -> None:
            partitions = consumer.list_topics(topic, timeout=CONNECT_TIMEOUT_S).topics[topic].partitions
            ends = []
            for partition in partitions:
                _, high = consumer.get_watermark_offsets(TopicPartition(topic, partition), timeout=CONNECT_TIMEOUT_S)
                ends.append(TopicPartition(topic, partition, high))
            consumer.assign(ends)

        await asyncio.to_thread(assign)
        self._consumer = consumer
        self._readers.append(self._loop.create_task(self._read_replies(consumer, session, handler)))
        return topic

    async def _read_replies(self, consumer: Consumer, session: str, handler: Callable[[bytes], Awaitable[None]]):
        while not self._closed:
            message = await self._poll(consumer)
            if message is None or message.error() is not None:
                continue
            if _text(_headers(message).get(SESSION_HEADER)) == session:  # another robot's: not ours to read
                await handler(message.value() or b"")

    async def send(self, body: bytes, envelope: Envelope, correlation: str, deadline_ms: float | None) -> None:
        headers = {**envelope.headers(), CORRELATION_HEADER: correlation}
        if envelope.reply:
            headers[REPLY_HEADER] = envelope.reply
        await self._produce(self.topic, body, envelope.robot, headers)

    # -- either end -----------------------------------------------------------------------------------------------

    async def wait_closed(self) -> None:
        """Returns once every broker is unreachable (librdkafka's _ALL_BROKERS_DOWN) or a client failed for good."""
        await self._lost.wait()

    async def close(self) -> None:
        self._closed = True
        self._lost.set()
        # each reader ends after its poll in flight (POLL_S): librdkafka's clients are closed only once none polls
        for reader in self._readers:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(reader, POLL_S * 20)
        consumer, self._consumer = self._consumer, None
        if consumer is not None:
            with contextlib.suppress(Exception):
                await asyncio.to_thread(consumer.close)  # commits what was settled
        producer, self._producer = self._producer, None
        if producer is not None:
            with contextlib.suppress(Exception):
                await asyncio.to_thread(producer.flush, 1.0)
        self._pollers.shutdown(wait=False)


def _resolve(done: asyncio.Future, error: Exception | None) -> None:
    if done.done():
        return
    if error is None:
        done.set_result(None)
    else:
        done.set_exception(error)


def _headers(message: Message) -> dict[str, bytes | None]:
    """A message's headers, the first of each name (a Kafka header may repeat, and its value may be None)."""
    found: dict[str, bytes | None] = {}
    for name, value in message.headers() or ():
        found.setdefault(name, value)
    return found


def _text(value: bytes | str | None) -> str | None:
    if isinstance(value, bytes):
        return value.decode(errors="replace")
    return value
