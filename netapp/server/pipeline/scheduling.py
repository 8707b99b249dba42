"""Which frame runs next: each session's bounded queue (newest wins) and the ready queue of sessions, taken round
robin so a fast robot cannot starve the others. A session with a frame in process goes back in line only when that
frame is done, so a robot never has two lanes and its results leave in order. A frame whose robot's deadline cannot
be met is taken out here, before inference is spent on it.

Turns are weighed by cost (deficit round robin): each session's frames cost the inference thread a measured time
(`Session.cost_s`: its decoding and preparing there, and its share of the model's call). At the head of the line a
session earns the cheapest session's cost; it runs once its credit covers its own cost, else it goes to the back.
So a robot sending 4K frames or a keyframe flood gets its share of the netapp's time, not more turns' worth; a
session alone (nobody else waiting) always runs. Costs within `ALIKE_COST_FACTOR` of the typical session's count as
the typical one: robots alike measure different costs by the machine's noise alone (another process preempting a
lane), and weighing their turns by it made their shares differ by as much; so they take plain turns, and only a robot
whose frames really cost more (or less) is weighed.

Robots of different priority classes wait in a line per class; which class goes next is stride scheduling by the
classes' weights (`netapp.server.pipeline.priorities.ClassTurns`): higher classes first, the lowest with a floor share.
The weighed turns above are within a class."""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from netapp.server.errors import SessionClosed
from netapp.server.pipeline.frame import Frame, resolve
from netapp.server.pipeline.next_turn import STREAMING_S, next_turn_in_s
from netapp.server.pipeline.priorities import DEFAULT_WEIGHTS, ClassTurns
from netapp.server.sessions import Session

Batch = list[tuple[Session, Frame]]
# What a turn is charged to its class before any session's cost is measured (the first batches): a little, so no
# class runs ahead by much on turns nobody measured.
UNMEASURED_TURN_S = 0.001
# Costs within this factor of the typical session's (the median) are charged as the typical cost (`turn_cost`): a
# batch's time on a busy machine says as much about what else ran as about its frame, while a 4K robot's frames
# cost several times a 640x480 one's (docs/benchmarks.md#start-storms).
ALIKE_COST_FACTOR = 1.5


def turn_cost(cost_s: float, typical_s: float) -> float:
    """What a session's turn is charged in its class's line: its measured `cost_s`, or `typical_s` where the two
    are within ALIKE_COST_FACTOR of each other (0: not measured)."""
    if cost_s <= 0 or typical_s / ALIKE_COST_FACTOR <= cost_s <= typical_s * ALIKE_COST_FACTOR:
        return typical_s if cost_s > 0 else 0.0
    return cost_s


@dataclass
class SessionQueue:
    """A session's frames waiting for inference, and the order they were received in."""

    session: Session
    pending: deque[Frame] = field(default_factory=deque)
    queued: bool = False  # in the ready queue (its class's line)
    busy: bool = False  # a frame of it is being processed: back in line once that is done, not before
    next_seq: int = 0
    last_seq: int = -1
    preparing: deque[tuple[Frame, asyncio.Future]] = field(default_factory=deque)  # on the prepare pool
    credit_s: float = 0.0  # deficit round robin: inference time earned at the head of the line, not yet spent


class Scheduler:
    """The sessions' queues and the ready queue. `drop(session, frame)` counts and answers a superseded frame."""

    def __init__(
        self, queue_size: int, drop: Callable[[Session, Frame], None], weights: tuple[float, ...] = DEFAULT_WEIGHTS
    ) -> None:
        self.queue_size = queue_size
        self._drop = drop
        self._queues: dict[str, SessionQueue] = {}
        self._classes = ClassTurns(weights)
        self._ready: list[deque[SessionQueue]] = [deque() for _ in weights]  # the ready queue: a line per class
        self._wakeup = asyncio.Event()  # set when a session lines up

    def queue(self, session: Session) -> SessionQueue:
        queue = self._queues.get(session.id)
        if queue is None:
            queue = SessionQueue(session)
            if not session.closed:  # a closed session's queue would never be removed
                self._queues[session.id] = queue
        return queue

    def next_seq(self, session: Session) -> int:
        """The receive order of a session's next frame, fixed before concurrent decoding can reorder frames."""
        queue = self.queue(session)
        queue.next_seq += 1
        return queue.next_seq

    def queues(self) -> int:
        """How many sessions have a queue (each open session that has sent a frame)."""
        return len(self._queues)

    def depth(self, session: Session) -> int:
        queue = self._queues.get(session.id)
        return len(queue.pending) if queue is not None else 0

    def waiting(self) -> int:
        """Frames waiting for inference, all sessions together."""
        return sum(len(q.pending) for q in list(self._queues.values()))

    def sessions(self) -> list[Session]:
        return [q.session for q in list(self._queues.values())]

    def clear(self, session: Session, exc: BaseException) -> None:
        """Take a session's waiting frames off its queue; their waiters get `exc`."""
        queue = self._queues.get(session.id)
        while queue is not None and queue.pending:
            resolve(queue.pending.popleft().waiter, exc=exc)

    def close(self, session: Session, exc: BaseException) -> None:
        """Forget a session that is going away; the waiters of its frames get `exc`."""
        self.clear(session, exc)
        self._queues.pop(session.id, None)

    def submit(self, session: Session, frame: Frame) -> None:
        """A prepared (or still undecoded) frame into its session's queue: the oldest waiting ones make room."""
        if session.closed:
            resolve(frame.waiter, exc=SessionClosed("the session was closed"))
            return
        queue = self.queue(session)
        if frame.seq < queue.last_seq:
            self._drop(session, frame)  # a newer frame of this robot was queued while this one decoded
            return
        queue.last_seq = frame.seq
        while len(queue.pending) >= self.queue_size:
            self._drop(session, queue.pending.popleft())
        queue.pending.append(frame)
        self._line_up(queue)

    def _line_up(self, queue: SessionQueue) -> None:
        """Into the ready queue, at the back, when it has a frame and none in process (so a robot never has two
        lanes, and its results leave in order)."""
        if queue.pending and not queue.queued and not queue.busy and not queue.session.closed:
            queue.queued = True
            line = self._ready[queue.session.priority]
            if not line:
                self._classes.wake(queue.session.priority)
            line.append(queue)
            self._wakeup.set()

    def release(self, batch: Batch) -> None:
        """A batch is done: its sessions may have their next frame processed."""
        for session, _ in batch:
            queue = self._queues.get(session.id)
            if queue is not None:
                queue.busy = False
                self._line_up(queue)

    def _weighed_turns(self, candidates: list[SessionQueue], max_batch: int, now_s: float) -> list[SessionQueue]:
        """Up to `max_batch` sessions from `candidates` then the ready queue, by deficit round robin within each
        class: one whose credit does not yet cover its cost goes to the back of its class's line while another
        session of its class waits. Each turn is charged to its class (`ClassTurns.charge`)."""
        typical, quantum = self._costs()
        pending = deque(candidates)
        turns: list[SessionQueue] = []
        while len(turns) < max_batch and (pending or self.has_ready()):
            queue = pending.popleft() if pending else self.take_ready()
            if queue.session.closed:  # gone while in line: out of it (its cost must not keep others waiting)
                queue.queued = False
                continue
            line = self._ready[queue.session.priority]
            cost = turn_cost(queue.session.cost_s, typical) or quantum
            queue.credit_s += quantum
            if queue.credit_s < cost and line:
                line.append(queue)  # still `queued`: at the back of its class's line
                continue
            queue.credit_s = max(0.0, queue.credit_s - cost)
            self._classes.charge(queue.session.priority, queue.session.cost_s or quantum or UNMEASURED_TURN_S, now_s)
            turns.append(queue)
        return turns

    def _costs(self) -> tuple[float, float]:
        """The typical measured cost (the median session's), and what a turn at the head of the line earns: the
        cheapest session's `turn_cost` ((0, 0): none measured, every session then runs at its turn: plain round
        robin)."""
        costs = sorted(q.session.cost_s for q in list(self._queues.values()) if q.session.cost_s > 0)
        if not costs:
            return 0.0, 0.0
        typical = costs[(len(costs) - 1) // 2]
        return typical, turn_cost(costs[0], typical)

    def next_turn_in_s(self, session: Session, since_turn_s: float, now_s: float) -> float:
        """When `session`'s next turn comes, its last one having started `since_turn_s` ago (`next_turn`), among the
        sessions streaming at `now_s` (monotonic seconds)."""
        others = [
            (q.session.priority, q.session.cost_s)
            for q in list(self._queues.values())
            if q.session is not session and now_s - q.session.last_seen < STREAMING_S
        ]
        weights, use = self._classes.weights, self._classes.use(now_s)
        return next_turn_in_s(session.priority, session.cost_s, since_turn_s, others, weights, use)

    def has_ready(self) -> bool:
        return any(self._ready)

    async def next_ready(self) -> SessionQueue:
        """The session whose turn it is, once one is ready."""
        while not self.has_ready():
            self._wakeup.clear()
            await self._wakeup.wait()
        return self.take_ready()

    def take_ready(self) -> SessionQueue:
        """The session at the head of the line of the class whose turn it is (IndexError: none is ready)."""
        waiting = [priority for priority, line in enumerate(self._ready) if line]
        if not waiting:
            raise IndexError("no session is ready")
        return self._ready[self._classes.pick(waiting)].popleft()

    def collect(
        self, queues: list[SessionQueue], max_batch: int, now_ns: int, expected_ns: float
    ) -> tuple[Batch, Batch]:
        """A batch: the next frame of each of the first `max_batch` sessions in the ready queue (`queues` first);
        and the frames taken out because they could not finish by their deadline (expected to take
        `expected_ns`), for the caller to count and answer."""
        queues = self._weighed_turns(queues, max_batch, now_ns / 1e9)
        batch: Batch = []
        late: Batch = []
        for queue in queues:
            queue.queued = False
            while not queue.session.closed and queue.pending:
                frame = queue.pending.popleft()
                if not frame.cannot_finish(now_ns, expected_ns):
                    batch.append((queue.session, frame))
                    queue.busy = True  # back of the line once this frame is done: round robin between robots
                    break
                late.append((queue.session, frame))
        return batch, late
