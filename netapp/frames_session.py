"""The robot's side of one `frames` connection (docs/protocol.md), free of I/O as h11 and wsproto are.

Every client that speaks `frames` drives one and keeps only its I/O (the socket, its threads or tasks, the waiting):
the robot's transport (`netapp.client.transports.frames`), RTP's control channel (`netapp.client.transports.rtp`),
`netapp watch` (`netapp.client.watch`) and the replica relay (`netapp.server.sources.relay`), which is why it lives
here, beside the wire format (`netapp.framing`), and imports neither side. It numbers the commands it builds and
matches their acknowledgements (an ack for no command it waits for is dropped: stale or made up); it reads each
netapp event into a typed one (`Acked`, `Refused`, `Moved`, `Results`, `FrameError`, `SessionInfo`); it holds the one
bound on what the netapp may send in a message (`MAX_MESSAGE_BYTES`), which its socket options carry.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

from netapp import wire_json
from netapp.frame import EncodedFrame
from netapp.framing import ACK_EVENT, CODECS, ERROR_EVENT, REFUSED_EVENT, pack_frame, read_event
from netapp.protocol import MOVE_EVENT, RESULTS_EVENT, SESSION_INFO_EVENT, CommandType

# What the netapp may send in one message (a result with its masks, a GET_STATE answer): past it websockets closes
# the connection (1009) before reading it. One bound for every frames client.
MAX_MESSAGE_BYTES = 16 * 1024 * 1024
CLOSE_TIMEOUT_S = 1.0  # closing waits this long for the netapp's close frame


@dataclass(frozen=True, slots=True)
class Command:
    """A command to send: its id (its acknowledgement repeats it) and its text message."""

    ident: int
    text: str


@dataclass(frozen=True, slots=True)
class Acked:
    """The acknowledgement of a command this session waits for: `answer` is the netapp's whole ack (`ok`,
    `message`, `session_id`; refused: `reason`, `retry_after_s`, `limit`; INIT with RTP: its port)."""

    ident: int
    answer: dict[str, Any]

    @property
    def ok(self) -> bool:
        return bool(self.answer.get("ok"))

    @property
    def message(self) -> str:
        return str(self.answer.get("message") or "")


@dataclass(frozen=True, slots=True)
class Refused:
    """The netapp refused the connection (a token, a draining replica: the error body); it closes it next."""

    body: dict[str, Any]


@dataclass(frozen=True, slots=True)
class Moved:
    """The replica is going away (draining): connect again through the Service."""

    reason: str


@dataclass(frozen=True, slots=True)
class Results:
    """A result message (as on every transport)."""

    data: dict[str, Any]


@dataclass(frozen=True, slots=True)
class FrameError:
    """An error about a frame or the session: `{"timestamp", "error", "reason"}`, Socket.IO's `data_error`."""

    data: dict[str, Any]


@dataclass(frozen=True, slots=True)
class SessionInfo:
    """What the netapp says of the session just before INIT's ack (its processor's `input_size`, ...)."""

    data: dict[str, Any]


Event = Acked | Refused | Moved | Results | FrameError | SessionInfo


class FramesSession:
    """One connection's protocol state: the commands awaiting their acknowledgement and the refusal, if any. Not
    thread-safe: a client whose threads share one holds its own lock around it."""

    def __init__(self, max_message_bytes: int = MAX_MESSAGE_BYTES) -> None:
        self.max_message_bytes = max_message_bytes
        self.refused: dict[str, Any] | None = None  # the netapp's `refused` event's body, once it came
        self._ids = itertools.count(1)
        self._waiting: set[int] = set()  # ids of commands whose acknowledgement is still to come

    def socket_options(self) -> dict[str, Any]:
        """What the WebSocket client (websockets, sync or asyncio) connects with: the one message bound, and no
        compression (JPEG and H.264 do not compress: deflate would only cost CPU)."""
        return {"max_size": self.max_message_bytes, "compression": None, "close_timeout": CLOSE_TIMEOUT_S}

    def command(self, cmd_type: CommandType, data: Any) -> Command:
        """A 5G-ERA command with a new id, awaited from now on."""
        ident = next(self._ids)
        self._waiting.add(ident)
        text = wire_json.dumps({"id": ident, "cmd_type": int(cmd_type), "clear_queue": False, "data": data})
        return Command(ident, text)

    def abandon(self, ident: int) -> None:
        """No longer wait for this command's acknowledgement (given up on it): a late one is dropped."""
        self._waiting.discard(ident)

    def frame(self, frame: EncodedFrame) -> bytes:
        """A frame's binary message; ValueError for a codec the protocol does not carry."""
        if frame.codec not in CODECS:
            raise ValueError(f"the frames protocol carries {sorted(CODECS)} frames, not {frame.codec}")
        return pack_frame(frame)

    def receive(self, text: Any) -> Event | None:
        """One message from the netapp -> its event; None for anything else (binary, over the bound, not an event,
        an acknowledgement of no command awaited here, an event with no use): every byte is the network's."""
        if isinstance(text, str) and len(text) > self.max_message_bytes:
            return None
        got = read_event(text)
        if got is None:
            return None
        name, message = got
        data = message.get("data")
        if name == ACK_EVENT:
            ident = message.get("id")
            if not isinstance(ident, int) or isinstance(ident, bool) or ident not in self._waiting:
                return None
            self._waiting.discard(ident)
            return Acked(ident, message)
        if name == RESULTS_EVENT:
            return Results(data) if isinstance(data, dict) else None
        if name == ERROR_EVENT:
            return FrameError(_body(data))
        if name == SESSION_INFO_EVENT:
            return SessionInfo(data) if isinstance(data, dict) else None
        if name == MOVE_EVENT:
            reason = data.get("reason") if isinstance(data, dict) else None
            return Moved(str(reason or "move"))
        if name == REFUSED_EVENT:
            self.refused = _body(data)
            return Refused(self.refused)
        return None


def _body(data: Any) -> dict[str, Any]:
    """An event's `data` as an error body (a broken netapp's anything as its text)."""
    return data if isinstance(data, dict) else {"error": str(data)}
