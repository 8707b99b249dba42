"""The dataplane's observer that publishes: each delivered result becomes one broker message (`netapp.broker.message`),
encoded once and offered to every `--publish` broker's `Publisher`, which never makes the data path wait."""

from __future__ import annotations

import asyncio
import hashlib
import logging
from pathlib import Path
from typing import Any

import numpy as np
from prometheus_client import CollectorRegistry

from netapp.broker.address import BrokerAddress
from netapp.broker.message import ModelIdentity, encode, result_message
from netapp.broker.publisher import Publisher
from netapp.sdk.processor import Processor
from netapp.server.brokers.metrics import BrokerMetrics
from netapp.server.sessions import Session

log = logging.getLogger(__name__)


def model_identity(processor: Processor) -> ModelIdentity:
    """The processor's name, and its model file's sha256 where it has one (a built-in's `config.model_path`)."""
    path = getattr(getattr(processor, "config", None), "model_path", None)
    digest = None
    if path is not None and Path(path).is_file():
        digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()
    return ModelIdentity(processor.name, digest)


class ResultPublishers:
    """A `ResultObserver` (netapp/server/pipeline/observers.py) over one `Publisher` per broker."""

    def __init__(self, publishers: list[Publisher], processor: Processor, netapp: str) -> None:
        self.publishers = publishers
        self.processor = processor
        self.netapp = netapp
        self.model = ModelIdentity(processor.name)  # its sha256 once `start` has read the file
        self._identifying: asyncio.Task | None = None

    @classmethod
    def build(
        cls, addresses: tuple[BrokerAddress, ...], processor: Processor, registry: CollectorRegistry
    ) -> ResultPublishers:
        metrics = BrokerMetrics(registry)
        publishers = [Publisher(a, events=metrics.events(a.redacted())) for a in addresses]
        return cls(publishers, processor, addresses[0].netapp if addresses else "")

    def start(self) -> None:
        """Start sending, on the event loop, without waiting: each publisher connects in its own task (a broker that
        is down delays nothing), and the model file is hashed off the loop."""
        for publisher in self.publishers:
            publisher.start()
        if self.publishers:
            self._identifying = asyncio.get_running_loop().create_task(self._identify())

    async def _identify(self) -> None:
        self.model = await asyncio.to_thread(model_identity, self.processor)

    async def close(self) -> None:
        if self._identifying is not None:
            self._identifying.cancel()
        await asyncio.gather(*(p.close() for p in self.publishers))

    def watched(self, session_id: str) -> bool:
        return False

    def report(self, session: Session, value: Any) -> None:
        pass

    def record(self, session: Session, message: dict[str, Any], image: np.ndarray | None) -> None:
        source = session.robot_id or session.id
        body = encode(
            result_message(message, netapp=self.netapp, source=source, session_id=session.id, model=self.model)
        )
        for publisher in self.publishers:
            topic, key = publisher.address.destination(source)
            publisher.offer(topic, body, key=key)

    def forget(self, session_id: str) -> None:
        pass
