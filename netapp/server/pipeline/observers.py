"""Who else sees the results: the pipeline and the dataplane publish to observers (the web page's live view is
one, registered by `netapp.server.app`), so the data path imports nothing of theirs."""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from netapp.server.sessions import Session


class ResultObserver(Protocol):
    """What an observer of the data path is told. Each call is cheap: it runs on the data path."""

    def watched(self, session_id: str) -> bool:
        """Whether to keep this session's decoded frames for it (asked for each frame, on the decoding thread)."""
        ...

    def report(self, session: Session, value: Any) -> None:
        """The robot's own report of its previous result's uplink and downlink (unchecked, as it arrived)."""
        ...

    def record(self, session: Session, message: dict[str, Any], image: np.ndarray | None) -> None:
        """A result delivered, with its decoded frame when `watched` asked for it."""
        ...

    def forget(self, session_id: str) -> None:
        """The session ended."""
        ...


class Observers:
    """Every registered observer, told in turn (itself a `ResultObserver`)."""

    def __init__(self) -> None:
        self._observers: list[ResultObserver] = []

    def add(self, observer: ResultObserver) -> None:
        self._observers.append(observer)

    def watched(self, session_id: str) -> bool:
        return any(o.watched(session_id) for o in self._observers)

    def report(self, session: Session, value: Any) -> None:
        for observer in self._observers:
            observer.report(session, value)

    def record(self, session: Session, message: dict[str, Any], image: np.ndarray | None) -> None:
        for observer in self._observers:
            observer.record(session, message, image)

    def forget(self, session_id: str) -> None:
        for observer in self._observers:
            observer.forget(session_id)
