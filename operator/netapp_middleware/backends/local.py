"""The local backend: each NetApp is a `netapp serve` process on this machine (development without a cluster).

A NetApp means here what it means to the operator: its command is the one a pod runs (`serve_command`), less only
what a cluster has (netapp_operator.render's `CLUSTER_ONLY_ARGS`, `CLUSTER_ONLY_ENV`). A field one machine cannot
honour (replicas, autoscaling, a GPU it lacks, a cluster's volume or Secret: `one_machine_refusal`) is refused, one
line that names it, before anything starts (`refuse`; the middleware answers the robot 422). The claims a netapp
writes (`state`, `engineCache`) are directories of the backend's work directory named after the claim; the image,
port and resources are a container's. A placement names a pool of its
own (`edge`, `cloud`, a pool's name; `local` without one): each NetApp is a separate process whichever its pool,
so pools differ only by name here, enough to try a switchover between them (their links differ as the robot's
route to them does, e.g. through bench/linkemu). Processes listen on free
loopback ports, are Ready once `/readyz` answers 200, and are stopped on delete and on shutdown. They also get
PR_SET_PDEATHSIG, so a middleware killed with SIGKILL leaves no netapp behind either.

A NetApp's model changes without a restart: `rollout` starts a shadow of the new model on the running process
(`POST /rollout` with an admin token made for that process), and `rollout_state` reports its comparison
(docs/rollouts.md). A netapp stopped with a rollout under way (its robots left, it slept) is asked for it once more
first, and its `rollout_sink` keeps the verdict, or why there is none.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import functools
import hashlib
import logging
import os
import re
import secrets
import shutil
import signal
import sys
import tempfile
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from netapp_operator.idle import QuietClock, idle_after_s, robots_in
from netapp_operator.rollouts import FIELDS, rollout_request
from netapp_operator.serve_command import Where, one_machine_refusal, serve_command, serve_env
from netapp_operator.spec import NetAppSpec, parse
from netapp_operator.wake_listener import WakeListener, waking_answer

from netapp.protocol import ADMIN_TOKEN_DIGEST_ENV
from netapp.serve_process import free_port, wait_http_ok

from .base import (
    DEPLOYING,
    FAILED,
    IDLE,
    READY,
    Claim,
    InstanceState,
    Recovered,
    RolloutRefused,
    RolloutSink,
    StateCallback,
)

log = logging.getLogger(__name__)

POOL = "local"
READY_POLL_S = 0.02  # how often a starting netapp's /readyz is asked: a robot waiting on it gets it this much sooner
WAKE_GRACE_S = 0.1  # from a robot's request at a sleeping netapp's port to its start (`_wake_soon`)
LAST_LOOK_S = 2.0  # how long a stopping netapp's GET /rollout may take: its robots' leaving waits on it


def local_where(spec: NetAppSpec, port: int, host: str, model: str | None, work_dir: Path) -> Where:
    """Where a netapp process of `spec` listens and keeps its files: `model` (a local path or URL) in place of the
    spec's, which it otherwise fetches itself; a claim it writes, a directory of `work_dir` named after the claim."""
    claims = work_dir / "claims"
    state = spec.state.volume_claim if spec.state is not None else None
    cache = spec.trt_cache.claim_name if spec.trt_cache is not None else None
    return Where(
        host=host,
        port=port,
        model_file=str(model) if model else None,
        state_dir=str(claims / str(state)) if state else str(work_dir / "state"),
        trt_cache_dir=str(claims / str(cache)) if cache else str(work_dir / "tensorrt"),
    )


def netapp_command(
    spec: dict[str, Any],
    port: int,
    *,
    base: Sequence[str],
    host: str = "127.0.0.1",
    model: str | None = None,
    work_dir: Path | None = None,
) -> list[str]:
    """The argv that serves `spec` on host:port (`serve_command`, the operator's too); `model` (a local path or URL)
    overrides the spec's model."""
    parsed = parse(spec)
    where = local_where(parsed, port, host, model, work_dir or Path(tempfile.gettempdir()) / "netapp-middleware")
    return [*base, *serve_command(parsed, where).args]


# Ours, not the netapp's: the token signing key above all, and our own netapp token (the spec says whose it needs).
PRIVATE_ENV_PREFIXES = ("NETAPP_MIDDLEWARE_", "NETAPP_ROBOT_SECRET", "NETAPP_TOKEN")


def netapp_env(spec: dict[str, Any], name: str, app: str) -> dict[str, str]:
    """Our environment less our secrets, the spec's env, and the variables a 5G-ERA netapp expects."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(PRIVATE_ENV_PREFIXES)}
    env.pop("OTEL_SERVICE_NAME", None)  # the OTel variables reach the netapp too (docs/tracing.md), not our name
    env.update(NETAPP_ID=name, NETAPP_NAME=app)
    env.update(serve_env(parse(spec)))
    return env


def has_gpu() -> bool:
    """Whether this machine has an NVIDIA GPU a netapp could use (its driver's device node)."""
    return os.path.exists("/dev/nvidiactl")


def resident_bytes(pid: int) -> int | None:
    """A process' resident set size (Linux /proc), None where it cannot be read."""
    try:
        with open(f"/proc/{pid}/status", encoding="ascii", errors="replace") as status:
            for line in status:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024  # kB
    except (OSError, ValueError, IndexError):
        return None
    return None


def refusal_in_spec_terms(answer: Any) -> str:
    """The netapp's refusal of a rollout in the words of the NetApp spec that asked for it: its `error` line (not
    the JSON around it), each of its field names as the spec writes it (`spec.rollout.minAgreement`, not
    `min_agreement`)."""
    try:
        body = answer.json()
        message = body["error"] if isinstance(body, dict) and isinstance(body.get("error"), str) else None
    except ValueError:
        message = None
    if message is None:
        return f"HTTP {answer.status_code}: {answer.text[:200]}"
    for spec_name, wire_name in FIELDS.items():
        message = re.sub(rf"\b{wire_name}\b", f"spec.rollout.{spec_name}", message)
    return message[:300]


def _die_with_parent() -> None:  # runs in the child between fork and exec
    with contextlib.suppress(Exception):
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


@dataclass(eq=False)
class _Process:
    proc: asyncio.subprocess.Process
    port: int
    log_path: Path
    pool: str = POOL
    monitor: asyncio.Task[None] | None = None
    stopping: bool = field(default=False)
    admin_token: str = field(default="", repr=False)  # starts its rollouts (POST /rollout); never logged
    # What starts it again after it slept (spec.scaling.idleToZero): its argv and environment, on the same port.
    argv: list[str] = field(default_factory=list)
    env: dict[str, str] = field(default_factory=dict, repr=False)
    idle_after_s: float | None = None
    asleep: bool = False
    wakes: int = 0  # each wake restarts its quiet clock: a robot just handed the URL has not connected yet
    listener: WakeListener | None = None  # on its port while it sleeps: a robot's request there wakes it


class LocalBackend:
    """Runs netapps as child processes; see the module docstring."""

    name = "local"

    def __init__(
        self,
        *,
        model: str | None = None,
        command: Sequence[str] | None = None,
        host: str = "127.0.0.1",
        ready_timeout_s: float = 180.0,
        stop_timeout_s: float = 10.0,
        idle_poll_s: float = 1.0,
        port_for: Callable[[str], int] | None = None,
        url_for: Callable[[str, str], str] | None = None,
        gpu: bool | None = None,
    ) -> None:
        self.model = model
        self.gpu = has_gpu() if gpu is None else gpu  # whether a spec may ask for one here
        # How a NetApp's port is chosen (by name); a free loopback port unless a caller needs a specific one.
        self.port_for = port_for or (lambda name: free_port(self.host))
        # Where robots reach a NetApp of a pool, given its own URL: itself, unless a caller puts a pool behind
        # something (bench/switchover.py: the edge pool behind an emulated link).
        self.url_for = url_for or (lambda pool, url: url)
        self.command = list(command or [sys.executable, "-m", "netapp", "serve"])
        self.host = host
        self.ready_timeout_s = ready_timeout_s
        self.stop_timeout_s = stop_timeout_s
        self.idle_poll_s = idle_poll_s  # how often a netapp that may sleep is asked for its robots (its /metrics)
        self._procs: dict[str, _Process] = {}
        self._report: StateCallback = lambda name, state: None
        # Its netapps' logs and the directories of the claims they write: made with the first netapp, gone with the
        # last one when no claim's directory is left in it, and at close (`make test` once left a hundred in /tmp).
        self._work_dir: Path | None = None
        # Readiness waits (netapp.serve_process.wait_http_ok) block a thread each, for as long as a netapp takes to load
        # its model: their own pool, so they never hold up the loop's default executor.
        self._waiters = ThreadPoolExecutor(max_workers=64, thread_name_prefix="netapp-ready")
        self._wakes: set[asyncio.Task[None]] = set()  # wakes a robot's request at a sleeping port started
        # Told of a rollout's last state just before its netapp stops (model_rollouts.ModelRollouts sets itself):
        # the netapp's own record of it goes with its process.
        self.rollout_sink: RolloutSink | None = None

    async def start(self, report: StateCallback) -> list[Recovered]:
        self._report = report
        return []  # our processes never outlive us (PR_SET_PDEATHSIG)

    async def record(self, name: str, claims: list[Claim]) -> None:
        """Nothing to record: the registry in memory is all there is, and it dies with the processes."""

    def refuse(self, spec: dict[str, Any]) -> str | None:
        """Why this machine cannot run `spec` as it says (one line naming the field), None when it can."""
        return one_machine_refusal(parse(spec), gpu=self.gpu)

    async def create(
        self,
        name: str,
        app: str,
        placement: str | None,
        spec: dict[str, Any],
        labels: dict[str, str],
        annotations: dict[str, str] | None = None,  # a process has nowhere to keep them
    ) -> None:
        parsed = parse(spec)
        refused = one_machine_refusal(parsed, gpu=self.gpu)
        if refused is not None:
            raise ValueError(refused)
        port = self.port_for(name)
        if self._work_dir is None:
            self._work_dir = Path(tempfile.mkdtemp(prefix="netapp-middleware-"))
        where = local_where(parsed, port, self.host, self.model, self._work_dir)
        for wanted, directory in ((parsed.state, where.state_dir), (parsed.trt_cache, where.trt_cache_dir)):
            if wanted is not None:
                Path(directory).mkdir(parents=True, exist_ok=True)
        argv = [*self.command, *serve_command(parsed, where).args]
        admin_token = secrets.token_urlsafe(32)
        env = {**netapp_env(spec, name, app), ADMIN_TOKEN_DIGEST_ENV: hashlib.sha256(admin_token.encode()).hexdigest()}
        pool = placement or parsed.placement.pool or POOL  # the robot's, else the spec's pinned pool, by name
        entry = _Process(proc=None, port=port, log_path=self._work_dir / f"{name}.log", pool=pool)  # type: ignore[arg-type]
        entry.admin_token, entry.argv, entry.env, entry.idle_after_s = admin_token, argv, env, idle_after_s(parsed)
        self._procs[name] = entry
        await self._launch(name, entry)

    async def _launch(self, name: str, entry: _Process) -> None:
        """Start the entry's netapp process (again, after a sleep) and follow it until Ready."""
        with open(entry.log_path, "ab") as log_file:
            entry.proc = await asyncio.create_subprocess_exec(
                *entry.argv,
                stdin=asyncio.subprocess.DEVNULL,
                stdout=log_file,
                stderr=asyncio.subprocess.STDOUT,
                env=entry.env,
                start_new_session=True,
                preexec_fn=_die_with_parent if sys.platform == "linux" else None,
            )
        entry.asleep = entry.stopping = False
        proc = entry.proc
        log.info("NetApp %s: started pid %d: %s", name, proc.pid, " ".join(entry.argv))
        message = f"starting pid {proc.pid} on port {entry.port}"
        self._report(name, InstanceState(DEPLOYING, pool=entry.pool, message=message))
        entry.monitor = asyncio.get_running_loop().create_task(self._follow(name, entry))

    async def wake(self, name: str) -> None:
        """Start a sleeping NetApp's process again, on its port (its URL unchanged); restart the quiet clock of a
        running one. Ready is reported as always, once its /readyz answers."""
        entry = self._procs.get(name)
        if entry is None:
            return
        entry.wakes += 1
        if not entry.asleep:
            return
        entry.asleep = False  # once: a burst of requests at its port wakes it once
        listener, entry.listener = entry.listener, None
        if listener is not None:
            await listener.close()
        log.info("NetApp %s: woken", name)
        await self._launch(name, entry)

    def _wake_soon(self, name: str) -> None:
        """A robot's request at a sleeping netapp's port: woken after WAKE_GRACE_S, so that the robot's next
        request (a refused handshake is followed by GET /readyz) still reads `waking` there rather than a closed
        port, and keeps trying."""

        async def wake_after_grace() -> None:
            await asyncio.sleep(WAKE_GRACE_S)
            await self.wake(name)

        task = asyncio.get_running_loop().create_task(wake_after_grace())
        self._wakes.add(task)
        task.add_done_callback(self._wakes.discard)

    async def delete(self, name: str) -> None:
        entry = self._procs.get(name)
        if entry is None:
            return
        await self._last_look(name, entry)
        if self._procs.pop(name, None) is not entry:
            return  # deleted meanwhile
        entry.stopping = True
        if entry.monitor is not None:
            entry.monitor.cancel()
        if entry.listener is not None:
            await entry.listener.close()
        await self._stop(entry)
        with contextlib.suppress(OSError):
            entry.log_path.unlink()
            entry.log_path.parent.rmdir()  # the last netapp's, and no claim's directory: nothing left behind
            self._work_dir = None
        log.info("NetApp %s: stopped (exit code %s)", name, entry.proc.returncode)

    async def announce(self, name: str, type_: str, reason: str, message: str) -> None:
        """No cluster to post Events to: the log says it."""
        log.log(logging.WARNING if type_ == "Warning" else logging.INFO, "NetApp %s: %s: %s", name, reason, message)

    async def close(self) -> None:
        await asyncio.gather(*(self.delete(name) for name in list(self._procs)))
        self._waiters.shutdown(wait=False, cancel_futures=True)
        if self._work_dir is not None:  # with the logs of netapps that failed: they go with the middleware
            shutil.rmtree(self._work_dir, ignore_errors=True)

    async def rollout(self, name: str, spec: dict[str, Any]) -> dict[str, Any]:
        """Try `spec`'s new model (`spec.rollout.candidate`, else `spec.model.url`) on NetApp `name`'s running
        netapp, restarting nothing: its shadow starts there. The rollout's state; ValueError saying why not."""
        body = rollout_request(spec)
        entry = self._procs.get(name)
        if entry is None or entry.proc is None or entry.proc.returncode is not None or entry.stopping:
            raise ValueError(f"NetApp {name} has no running netapp here: deploy it first")
        headers = {"Authorization": f"Bearer {entry.admin_token}"}
        answer = await self._rollout_call("post", entry, json=body, headers=headers)
        if answer.status_code != 202:
            raise RolloutRefused(f"NetApp {name} refused the rollout: {refusal_in_spec_terms(answer)}")
        log.info("NetApp %s: rollout of %s started", name, body["candidate"])
        return answer.json()

    async def rollout_state(self, name: str) -> dict[str, Any] | None:
        """NetApp `name`'s rollout as its netapp reports it (GET /rollout); None when it is not running; ValueError
        when it does not answer."""
        entry = self._procs.get(name)
        if entry is None or entry.proc.returncode is not None:
            return None
        answer = await self._rollout_call("get", entry)
        if answer.status_code != 200:  # running, not answering as it should: asked again, not taken as gone
            raise ValueError(f"NetApp {name} answered GET /rollout with HTTP {answer.status_code}")
        return answer.json()

    async def _last_look(self, name: str, entry: _Process) -> None:
        """Before NetApp `name`'s netapp stops: a rollout under way there is read once more (bounded) and handed to
        the sink, which keeps its verdict or says why there is none."""
        sink = self.rollout_sink
        if sink is None or not sink.under_way(name):
            return
        state = None
        if entry.proc is not None and entry.proc.returncode is None:
            try:
                answer = await self._rollout_call("get", entry, timeout_s=LAST_LOOK_S)
                state = answer.json() if answer.status_code == 200 else None
            except ValueError:  # not answering (or not JSON): what was seen last is what is kept
                state = None
        sink.ended(name, state if isinstance(state, dict) else None)

    async def _rollout_call(self, method: str, entry: _Process, timeout_s: float = 10.0, **kwargs: Any) -> Any:
        import requests

        url = f"http://{self.host}:{entry.port}/rollout"
        call = functools.partial(getattr(requests, method), url, timeout=timeout_s, **kwargs)
        try:
            return await asyncio.get_running_loop().run_in_executor(self._waiters, call)
        except requests.RequestException as exc:
            raise ValueError(f"cannot reach the netapp at {url}: {exc}") from None

    def pids(self) -> dict[str, int]:
        """Running netapp processes by NetApp name (for diagnostics and tests)."""
        return {name: entry.proc.pid for name, entry in self._procs.items()}

    def usage(self, name: str) -> dict[str, int]:
        """What a netapp process holds: its pid and resident memory (`rssBytes`, from /proc); {} when not running."""
        entry = self._procs.get(name)
        if entry is None or entry.proc.returncode is not None:
            return {}
        return {"pid": entry.proc.pid, **({"rssBytes": rss} if (rss := resident_bytes(entry.proc.pid)) else {})}

    async def _follow(self, name: str, entry: _Process) -> None:
        url = f"http://{self.host}:{entry.port}"
        gave_up = threading.Event()
        wait = functools.partial(
            wait_http_ok, f"{url}/readyz", entry.proc, self.ready_timeout_s, interval_s=READY_POLL_S, cancel=gave_up
        )
        try:
            await asyncio.get_running_loop().run_in_executor(self._waiters, wait)
        except RuntimeError:
            if entry.proc.returncode is None:  # the deadline passed; an exit is reported below
                message = f"not ready after {self.ready_timeout_s:.0f} s; log: {self._tail(entry)}"
                self._report(name, InstanceState(FAILED, pool=entry.pool, message=message))
                return
        else:
            public = self.url_for(entry.pool, url)
            self._report(name, InstanceState(READY, url=public, pool=entry.pool, message="ready"))
        finally:
            gave_up.set()  # a cancelled follower (delete, shutdown) ends the wait in its thread too
        if entry.idle_after_s is not None and await self._slept(name, entry, url):
            return
        code = await entry.proc.wait()
        if not entry.stopping:
            message = f"netapp process exited with code {code}; log: {self._tail(entry)}"
            self._report(name, InstanceState(FAILED, pool=entry.pool, message=message))

    async def _slept(self, name: str, entry: _Process, url: str) -> bool:
        """Ask the Ready netapp for its robots (its /metrics) every `idle_poll_s`; once it served none for
        `idle_after_s`, stop its process and report it Idle, its URL kept (`wake` starts it again). False when the
        process exited by itself."""
        import requests

        assert entry.idle_after_s is not None
        clock, loop = QuietClock(), asyncio.get_running_loop()
        get = functools.partial(requests.get, f"{url}/metrics", timeout=self.idle_poll_s + 1)
        while entry.proc.returncode is None:
            await asyncio.sleep(self.idle_poll_s)
            try:
                answer = await loop.run_in_executor(self._waiters, get)
                robots = robots_in(answer.text) if answer.status_code == 200 else None
            except requests.RequestException:
                robots = None
            quiet_s = clock.observe(loop.time(), str(entry.wakes), entry.proc.returncode is None, robots)
            if quiet_s >= entry.idle_after_s:
                wakes, entry.stopping = entry.wakes, True  # no rollout starts on it from here (`rollout`)
                await self._last_look(name, entry)
                await self._stop(entry)
                log.info("NetApp %s: no robot for %.1f s: stopped until woken", name, quiet_s)
                if entry.wakes != wakes:  # a robot asked while it stopped: up again at once
                    await self._launch(name, entry)
                    return True
                entry.asleep = True
                entry.listener = await self._listen(name, entry.port)
                message = "idle: no robot; a robot's request for it wakes it"
                self._report(
                    name, InstanceState(IDLE, url=self.url_for(entry.pool, url), pool=entry.pool, message=message)
                )
                return True
        return False

    async def _listen(self, name: str, port: int) -> WakeListener | None:
        def answer(head: bytes) -> bytes:
            self._wake_soon(name)
            return waking_answer()

        listener = WakeListener(answer)
        try:
            await listener.open(self.host, port)
        except OSError as exc:  # its port taken meanwhile: a robot there is refused until the middleware wakes it
            log.warning("NetApp %s: cannot listen on port %d while it sleeps: %s", name, port, exc)
            return None
        return listener

    async def _stop(self, entry: _Process) -> None:
        if entry.proc.returncode is None:
            for sig, wait_s in ((signal.SIGTERM, self.stop_timeout_s), (signal.SIGKILL, None)):
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(entry.proc.pid, sig)  # the whole session: a netapp's own workers too
                try:
                    await asyncio.wait_for(entry.proc.wait(), wait_s)
                    break
                except asyncio.TimeoutError:
                    log.warning("pid %d ignored SIGTERM for %.0f s; killing", entry.proc.pid, wait_s)
        else:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(entry.proc.pid, signal.SIGKILL)  # leftovers of an exited netapp's session

    @staticmethod
    def _tail(entry: _Process, limit: int = 800) -> str:
        try:
            text = entry.log_path.read_bytes()[-limit:].decode(errors="replace")
        except OSError:
            return "(no log)"
        return " | ".join(line for line in text.splitlines() if line.strip())
