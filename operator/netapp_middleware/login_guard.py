"""What logins may cost: scrypt under a small concurrency limit, and failed logins rate-limited.

Each scrypt hash takes 16 MiB and ~50 ms of a core. Unbounded, 16 concurrent wrong-secret logins took 370 MB (the
pod's limit is 256Mi) and 100 of them pushed /healthz past its liveness timeout. So hashes run on a pool of
`max_hashing` threads of their own (a login waits up to `wait_s` for one, then gets 503): their own, because glibc
keeps a freed 16 MiB block in the arena of the thread that used it, so scrypt on any of the 40 request threads left
up to 40 x 16 MiB resident. And an id or an address with `max_failures` failed logins in the last `window_s`
seconds is refused before any hashing (429 with Retry-After) until the oldest failure ages out.
"""

from __future__ import annotations

import math
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout

from .auth import AuthError, RobotRegistry

SCRYPT_MEMORY_BYTES = 16 * 1024 * 1024  # n=2**14, r=8: 128 * r * n bytes
DEFAULT_MAX_HASHING = 2  # 32 MiB of hashing at once, in a 256Mi pod
DEFAULT_MAX_FAILURES = 10
DEFAULT_WINDOW_S = 60.0
MAX_QUEUED = 64  # logins waiting for a hashing thread; more are refused at once (503) rather than queued
MAX_TRACKED = 10_000  # ids and addresses remembered; the oldest are forgotten first (bounded memory)


class TooManyFailures(Exception):
    """Too many failed logins for this robot id or address lately; `retry_after_s` says when to try again."""

    def __init__(self, message: str, retry_after_s: int) -> None:
        super().__init__(message)
        self.retry_after_s = retry_after_s


class Busy(Exception):
    """Every hashing slot stayed taken for `wait_s`: the middleware is under a login flood."""

    retry_after_s = 1


class LoginGuard:
    """Wraps `RobotRegistry.authenticate` for the login routes (thread-safe: they run in the threadpool)."""

    def __init__(
        self,
        max_hashing: int = DEFAULT_MAX_HASHING,
        max_failures: int = DEFAULT_MAX_FAILURES,
        window_s: float = DEFAULT_WINDOW_S,
        wait_s: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.max_hashing, self.max_failures, self.window_s, self.wait_s = max_hashing, max_failures, window_s, wait_s
        self._hashing = ThreadPoolExecutor(max_hashing, thread_name_prefix="scrypt")
        self._waiting = 0  # logins queued for or in the hashing pool
        self._clock = clock
        self._lock = threading.Lock()
        self._failures: OrderedDict[str, deque[float]] = OrderedDict()
        self.refused = 0  # logins refused by the rate limit or for lack of a slot, for the logs and tests

    def authenticate(self, robots: RobotRegistry, robot_id: str, secret: str, address: str | None) -> None:
        """AuthError for wrong credentials, TooManyFailures or Busy before any hashing when refused."""
        keys = [f"robot:{robot_id}"] + ([f"address:{address}"] if address else [])
        self._check(keys)
        busy = Busy(f"too many logins at once (at most {self.max_hashing} are checked at a time): retry shortly")
        with self._lock:
            if self._waiting >= MAX_QUEUED:
                self.refused += 1
                raise busy
            self._waiting += 1
        try:
            job = self._hashing.submit(robots.authenticate, robot_id, secret)
            try:
                try:
                    job.result(timeout=self.wait_s)
                except FutureTimeout:
                    if job.cancel():  # still waiting for a hashing thread: refused
                        self.refused += 1
                        raise busy from None
                    job.result()  # started: a hash takes ~50 ms, let it finish
            except AuthError:
                self._fail(keys)
                raise
        finally:
            with self._lock:
                self._waiting -= 1

    def _check(self, keys: list[str]) -> None:
        now = self._clock()
        with self._lock:
            for key in keys:
                times = self._failures.get(key)
                if times is None:
                    continue
                while times and times[0] <= now - self.window_s:
                    times.popleft()
                if len(times) >= self.max_failures:
                    self.refused += 1
                    retry = max(1, math.ceil(times[0] + self.window_s - now))
                    kind = key.partition(":")[0]
                    raise TooManyFailures(
                        f"too many failed logins for this {kind} ({self.max_failures} in {self.window_s:.0f} s): "
                        f"retry in {retry} s",
                        retry,
                    )

    def _fail(self, keys: list[str]) -> None:
        now = self._clock()
        with self._lock:
            for key in keys:
                times = self._failures.pop(key, None) or deque(maxlen=self.max_failures)
                times.append(now)
                self._failures[key] = times  # most recently failed last
            while len(self._failures) > MAX_TRACKED:
                self._failures.popitem(last=False)
