"""Real message brokers on free loopback ports, for the broker channel's tests and benches (docs/broker.md).

- RabbitMQ (Debian's `rabbitmq-server`) runs as its own user `rabbitmq` with every path of its state (database, logs,
  feature flags, plugins) in a temporary folder that user owns, and its own Erlang port mapper port, so it never
  meets a system RabbitMQ or another test's. It is started with `setpriv`, not Debian's wrapper (whose `su` starts a
  session that a process-group kill never reaches), and listens after 5 to 10 s.
- Mosquitto (Debian's `mosquitto`) listens on loopback only, anonymous, MQTT 5, with `set_tcp_nodelay true` (its
  default leaves Nagle on: the tail of a 94 KB frame waited for the netapp's delayed ACK, about 40 ms a frame); it
  starts in well under a second, so tests take it down and up again (`restart`, same port) to make an outage.
- Kafka: no broker ships here. `KafkaMock` is librdkafka's mock cluster (confluent-kafka's `test.mock.num.brokers`),
  an in-process test double of the Kafka protocol that listens on a real loopback port: not Kafka, so every test that
  uses it says so, and `kafka_bootstrap()` returns a real broker's address instead when KAFKA_BOOTSTRAP is set.

    with Mosquitto() as broker:
        print(broker.url)  # mqtt://127.0.0.1:PORT
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path

from netapp.serve_process import free_port

RABBITMQ_HINT = (
    "RabbitMQ is not installed: `apt-get install -y rabbitmq-server` (Debian's package; .ci/run installs it)"
)
MOSQUITTO_HINT = "Mosquitto is not installed: `apt-get install -y mosquitto` (Debian's package; .ci/run installs it)"
KAFKA_HINT = "confluent-kafka is not installed: `pip install 'netapp-toolkit[broker]'` (its librdkafka has the mock)"

RABBITMQ_SERVER = "/usr/lib/rabbitmq/bin/rabbitmq-server"
RABBITMQCTL = "/usr/lib/rabbitmq/bin/rabbitmqctl"  # not /usr/sbin's wrapper, which resets HOME (the Erlang cookie)
RABBITMQ_USER = "rabbitmq"
AS_RABBITMQ = ("setpriv", "--reuid", RABBITMQ_USER, "--regid", RABBITMQ_USER, "--init-groups")


def wait_listening(port: int, process: subprocess.Popen, timeout_s: float, what: str) -> None:
    """Until something accepts on 127.0.0.1:`port`; raises when `process` exits or `timeout_s` passes."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"{what} exited with {process.returncode} before listening on {port}")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                return
        except OSError:
            time.sleep(0.05)  # polling the listening socket with a deadline
    raise RuntimeError(f"{what} did not listen on {port} within {timeout_s} s")


def wait_amqp(port: int, process: subprocess.Popen, timeout_s: float) -> None:
    """Until RabbitMQ on 127.0.0.1:`port` answers AMQP's protocol header (it accepts connections a moment before it
    speaks AMQP, closing them meanwhile); raises when `process` exits or `timeout_s` passes."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"rabbitmq-server exited with {process.returncode}")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=2.0) as probe:
                probe.sendall(b"AMQP\x00\x00\x09\x01")
                if probe.recv(1) == b"\x01":  # a method frame: Connection.Start
                    return
        except OSError:
            pass
        time.sleep(0.05)  # polling with a deadline
    raise RuntimeError(f"rabbitmq-server did not speak AMQP on {port} within {timeout_s} s")


def stop_group(process: subprocess.Popen | None, timeout_s: float = 10.0) -> None:
    """SIGTERM to the process group `process` leads (it was started with start_new_session), SIGKILL after
    `timeout_s`."""
    if process is None or process.poll() is not None:
        return
    for sig, wait_s in ((signal.SIGTERM, timeout_s), (signal.SIGKILL, 5.0)):
        try:
            os.killpg(process.pid, sig)
        except ProcessLookupError:
            return
        try:
            process.wait(timeout=wait_s)
            return
        except subprocess.TimeoutExpired:
            continue


class Mosquitto:
    """Mosquitto on a free loopback port; `restart()` takes it down and up on the same port (an outage)."""

    def __init__(self, persistent: bool = False) -> None:
        """`persistent`: sessions and their queued messages are kept across a `restart` (saved at shutdown)."""
        binary = shutil.which("mosquitto") or ("/usr/sbin/mosquitto" if os.path.exists("/usr/sbin/mosquitto") else None)
        if binary is None:
            raise FileNotFoundError(MOSQUITTO_HINT)
        self._binary = binary
        self.port = free_port()
        self.url = f"mqtt://127.0.0.1:{self.port}"
        self._dir = Path(tempfile.mkdtemp(prefix="netapp-mosquitto-"))
        self._config = self._dir / "mosquitto.conf"
        keep = f"persistence true\npersistence_location {self._dir}/\n" if persistent else "persistence false\n"
        if os.geteuid() == 0:  # started as root, mosquitto drops to its own user, which must write its database
            keep += "user root\n"
        # set_tcp_nodelay: as docs/broker.md asks of every Mosquitto that carries frames
        self._config.write_text(f"listener {self.port} 127.0.0.1\nallow_anonymous true\nset_tcp_nodelay true\n{keep}")
        self._process: subprocess.Popen | None = None

    def start(self, timeout_s: float = 10.0) -> Mosquitto:
        self._process = subprocess.Popen(
            [self._binary, "-c", str(self._config)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
        wait_listening(self.port, self._process, timeout_s, "mosquitto")
        return self

    def down(self) -> None:
        stop_group(self._process)
        self._process = None

    def restart(self) -> None:
        self.down()
        self.start()

    @property
    def pid(self) -> int | None:
        """The broker's process (its group's leader; the broker runs in it or below it)."""
        return None if self._process is None else self._process.pid

    def stop(self) -> None:
        self.down()
        shutil.rmtree(self._dir, ignore_errors=True)

    def __enter__(self) -> Mosquitto:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


class RabbitMQ:
    """RabbitMQ as the `rabbitmq` user, its state in a temporary folder, on free loopback ports (AMQP, Erlang
    distribution, port mapper). Run as root (the tests here are); `url` is amqp://guest:guest@127.0.0.1:PORT/ (the
    guest user may log in from loopback only)."""

    def __init__(self) -> None:
        if not os.path.exists(RABBITMQ_SERVER) or shutil.which("setpriv") is None:
            raise FileNotFoundError(RABBITMQ_HINT)
        self.port = free_port()
        self.url = f"amqp://guest:guest@127.0.0.1:{self.port}/"
        self._dist_port = free_port()
        self._epmd_port = free_port()
        self._dir = Path(tempfile.mkdtemp(prefix="netapp-rabbitmq-"))
        self._name = f"netapp{self.port}@localhost"
        self._process: subprocess.Popen | None = None

    def environment(self) -> dict[str, str]:
        """Every path RabbitMQ writes in the temporary folder (else it fails to create its feature flags file)."""
        folder = str(self._dir)
        return {
            "PATH": os.environ.get("PATH", "/usr/bin:/bin"),
            "HOME": folder,
            "RABBITMQ_MNESIA_BASE": f"{folder}/mnesia",
            "RABBITMQ_LOG_BASE": f"{folder}/log",
            "RABBITMQ_FEATURE_FLAGS_FILE": f"{folder}/feature_flags",
            "RABBITMQ_ENABLED_PLUGINS_FILE": f"{folder}/enabled_plugins",
            "RABBITMQ_NODE_PORT": str(self.port),
            "RABBITMQ_NODE_IP_ADDRESS": "127.0.0.1",
            "RABBITMQ_DIST_PORT": str(self._dist_port),
            "RABBITMQ_NODENAME": self._name,
            "ERL_EPMD_PORT": str(self._epmd_port),
            "ERL_EPMD_ADDRESS": "127.0.0.1",
        }

    def start(self, timeout_s: float = 60.0) -> RabbitMQ:
        (self._dir / "enabled_plugins").write_text("[].\n")
        shutil.chown(self._dir, RABBITMQ_USER, RABBITMQ_USER)
        shutil.chown(self._dir / "enabled_plugins", RABBITMQ_USER, RABBITMQ_USER)
        self._log = open(self._dir / "console.log", "ab")  # noqa: SIM115 (closed in stop)
        self._process = subprocess.Popen(
            [*AS_RABBITMQ, RABBITMQ_SERVER],
            env=self.environment(),
            cwd=self._dir,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        try:
            wait_listening(self.port, self._process, timeout_s, "rabbitmq-server")
            wait_amqp(self.port, self._process, timeout_s)
        except RuntimeError as exc:
            tail = (self._dir / "console.log").read_text(errors="replace")[-2000:]
            self.stop()
            raise RuntimeError(f"{exc}\n{tail}") from None
        return self

    def ctl(self, *args: str, timeout_s: float = 30.0) -> str:
        """rabbitmqctl against this node (e.g. `close_all_connections why`), its output."""
        done = subprocess.run(
            [*AS_RABBITMQ, RABBITMQCTL, "-n", self._name, *args],
            env=self.environment(),
            cwd=self._dir,
            capture_output=True,
            text=True,
            timeout=timeout_s,
        )
        if done.returncode != 0:
            raise RuntimeError(f"rabbitmqctl {' '.join(args)}: {done.stderr or done.stdout}")
        return done.stdout

    def down(self) -> None:
        """Stop the node, keeping its state (the durable queues) for `start` on the same ports: an outage."""
        stop_group(self._process, timeout_s=20.0)
        self._process = None
        if getattr(self, "_log", None) is not None:
            self._log.close()
            self._log = None

    @property
    def pid(self) -> int | None:
        """The broker's process (its group's leader; the broker runs in it or below it)."""
        return None if self._process is None else self._process.pid

    def stop(self) -> None:
        self.down()
        epmd = shutil.which("epmd")
        if epmd is not None:  # the port mapper the node started outlives it
            subprocess.run([epmd, "-port", str(self._epmd_port), "-kill"], capture_output=True, timeout=10)
        shutil.rmtree(self._dir, ignore_errors=True)

    def __enter__(self) -> RabbitMQ:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


class KafkaMock:
    """librdkafka's mock cluster (one broker), in this process, listening on a loopback port: a test double of the
    Kafka protocol, not Kafka. Kept alive by the producer that owns it; `bootstrap` is its host:port."""

    def __init__(self) -> None:
        try:
            from confluent_kafka import Producer
        except ImportError:
            raise FileNotFoundError(KAFKA_HINT) from None
        self._owner = Producer({"test.mock.num.brokers": 1})
        brokers = self._owner.list_topics(timeout=10).brokers
        broker = next(iter(brokers.values()))
        self.bootstrap = f"{broker.host}:{broker.port}"
        self.url = f"kafka://{self.bootstrap}/"

    def stop(self) -> None:
        self._owner.flush(1)
        self._owner = None

    def __enter__(self) -> KafkaMock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def kafka_bootstrap() -> str | None:
    """A real Kafka's bootstrap address when KAFKA_BOOTSTRAP is set (then the tests run against it)."""
    return os.environ.get("KAFKA_BOOTSTRAP") or None
