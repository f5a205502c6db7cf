"""A launched process graph for the bench to drive and watch, and the CPU time of a process.

:class:`GraphUnderTest` runs ``sensor-agent launch FILE`` in a subprocess with a private
runtime directory; the bench may play one of the graph's ``[[external]]`` publishers and
listens to the topics no process of the graph reads (its last stages' outputs), and to any
others it names.
"""

from __future__ import annotations

import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from types import TracebackType

import numpy as np

from agent.arrays import FloatArray
from agent.runtime import topics
from agent.runtime.bus import Bus
from agent.runtime.launch import GraphSpec, load_launch
from agent.runtime.messages import Header, Odometry, VehicleState, decode
from processes.launcher import live_pids

ROOT = Path(__file__).resolve().parents[1]
START_TIMEOUT_S = 20.0
STOP_TIMEOUT_S = 20.0
_CPUCLOCK_SCHED = 2  # the kernel's CPUCLOCK_SCHED: CPU time in ns, all threads of a process


def launch_variant(source: Path, directory: Path, **defaults: str) -> Path:
    """A copy of the launch file ``source`` in ``directory`` with ``[defaults]`` keys set.

    Each value is TOML text (``restart='"never"'``, ``max_restarts="100"``): a key already in
    ``[defaults]`` has its line replaced, another is added; ``"../"`` paths are made absolute,
    since the copy lives elsewhere. The copy is loaded once, so a launch file that changed
    shape fails here, naming the problem.
    """
    text = source.read_text().replace('"../', f'"{source.resolve().parent.parent}/')
    head, sep, rest = text.partition("[defaults]\n")
    if not sep:
        raise ValueError(f"{source} has no [defaults] table to change")
    table, sep2, tail = rest.partition("\n[")
    for key, value in defaults.items():
        line = f"{key} = {value}"
        table, found = re.subn(rf"(?m)^{re.escape(key)} *=.*$", line, table)
        if not found:
            table = f"{line}\n{table}"
    path = directory / source.name
    path.write_text(head + sep + table + sep2 + tail)
    load_launch(path)
    return path


def final_topics(graph: GraphSpec) -> list[str]:
    """Topics of the graph that no process of it reads: the last stages' outputs."""
    produced = [t for p in graph.processes for t in p.outputs]
    read = {t for p in graph.processes for t in p.inputs}
    return [t for t in produced if t not in read]


def process_cpu_s(pid: int) -> float:
    """CPU seconds a process has used, to the nanosecond, over all its threads (Linux).

    Reads the process's CPU-time clock (what ``clock_getcpuclockid(pid)`` returns, built as
    the kernel's ``MAKE_PROCESS_CPUCLOCK``): unlike ``/proc/PID/stat`` it is not counted in
    10 ms ticks, and unlike ``/proc/PID/schedstat`` it covers every thread, ZeroMQ's I/O
    thread included, and threads that have ended. ``OSError`` if the process is gone.
    """
    return time.clock_gettime_ns((~pid << 3) | _CPUCLOCK_SCHED) / 1e9


class GraphUnderTest:
    """``sensor-agent launch FILE`` in a subprocess, with the bench playing an external.

    Use as a context manager: the launcher is stopped (SIGINT, then SIGKILL), the bench's
    sockets closed and the runtime directory removed, on error too.
    """

    def __init__(
        self,
        launch_file: Path,
        play: str | None,
        listen: tuple[str, ...] = (),
        record: Path | None = None,
    ) -> None:
        self.dir = Path(tempfile.mkdtemp(prefix="lepb"))
        self.runtime = self.dir / "rt"
        self.bus: Bus | None = None
        # The graph's log goes to a file: a pipe nobody reads would block it once full.
        with (self.dir / "launch.log").open("wb") as log:
            self.proc = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "cli.main",
                    "launch",
                    str(launch_file),
                    "--runtime-dir",
                    str(self.runtime),
                    *(["--record", str(record)] if record is not None else []),
                ],
                cwd=ROOT,
                stdout=subprocess.DEVNULL,
                stderr=log,
            )
        try:
            deadline = time.monotonic() + START_TIMEOUT_S
            while not (self.runtime / "graph.json").exists():
                if time.monotonic() > deadline or self.proc.poll() is not None:
                    raise RuntimeError(f"graph {launch_file} did not start: {self.log_tail()}")
                time.sleep(0.02)
            self.graph = GraphSpec.from_json((self.runtime / "graph.json").read_text())
            endpoint = None
            if play is not None:
                endpoint = next(e.endpoint for e in self.graph.externals if e.name == play)
            self.bus = Bus(endpoint)
            publishers = self.graph.publishers()
            connected: set[str] = set()
            for topic in dict.fromkeys([*final_topics(self.graph), *listen]):
                endpoint = publishers[topic][1]
                if endpoint not in connected:
                    self.bus.subscriber.connect(endpoint)
                    connected.add(endpoint)
                self.bus.subscriber.subscribe(topic)
        except BaseException:
            self.stop()
            raise

    def log_tail(self, lines: int = 5) -> str:
        """The graph's last log lines (for an error message)."""
        log = (self.dir / "launch.log").read_text(errors="replace").strip().splitlines()
        return " | ".join(log[-lines:]) if log else "(no log output)"

    def listen(self) -> Bus:
        """The bench's sockets (an error once they are closed)."""
        if self.bus is None:
            raise RuntimeError("the bench's sockets on the graph are closed")
        return self.bus

    def wait_subscribed(self, topic: str, timeout_s: float = 20.0) -> None:
        """Until every process that reads ``topic`` has joined the bench's publisher."""
        bus = self.listen()
        wanted = len(self.graph.subscribers(topic))
        deadline = time.monotonic() + timeout_s
        publisher = bus.publisher
        while publisher is not None and publisher.subscriber_count(topic) < wanted:
            if time.monotonic() > deadline or self.proc.poll() is not None:
                raise RuntimeError(f"nobody subscribed to {topic} within {timeout_s} s")
            bus.poll_subscriptions(0.02)

    def pids(self) -> dict[str, int]:
        """Each process of the graph by name, and the launcher as ``launcher``."""
        return {**live_pids(self.runtime), "launcher": self.proc.pid}

    def close_bus(self) -> None:
        """Stop listening: the graph then runs as it would without the bench."""
        if self.bus is not None:
            self.bus.close()
            self.bus = None

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.close_bus()
        shutil.rmtree(self.dir, ignore_errors=True)

    def __enter__(self) -> GraphUnderTest:
        return self

    def __exit__(
        self, _t: type[BaseException] | None, _e: BaseException | None, _tb: TracebackType | None
    ) -> None:
        self.stop()


def vehicle_state_of(odometry: Odometry, intent_xy: FloatArray | None = None) -> VehicleState:
    """The vehicle controller's part, played by a bench: its odometry as the agent's vehicle
    state, with ``intent_xy`` (k, 2) ``odom`` waypoints ahead (default none)."""
    if intent_xy is None:
        intent_xy = np.zeros((0, 2))
    return VehicleState(
        header=Header(stamp_ns=odometry.header.stamp_ns, frame_id="odom"),
        x_m=odometry.x_m, y_m=odometry.y_m, yaw_rad=odometry.yaw_rad,
        speed_m_s=odometry.speed_m_s, yaw_rate_rad_s=odometry.yaw_rate_rad_s,
        pose_covariance=odometry.pose_covariance, intent_xy=intent_xy,
    )  # fmt: skip


class OdometryRelay:
    """Plays a graph's ``controller`` in a thread of its own: every ``odometry`` of the world
    process goes back out as the ``vehicle_state`` (what the vehicle controller of a later
    release does), so that tracking and the planner work while a bench watches the graph.

    Use as a context manager; its sockets live and die in its thread.
    """

    def __init__(self, graph: GraphUnderTest, external: str = "controller") -> None:
        self.endpoint = next(e.endpoint for e in graph.graph.externals if e.name == external)
        self.source = graph.graph.publishers()[topics.ODOMETRY][1]
        self.relayed = 0
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._run, name="odometry-relay", daemon=True)

    def _run(self) -> None:
        bus = Bus(self.endpoint)
        try:
            bus.subscriber.connect(self.source)
            bus.subscriber.subscribe(topics.ODOMETRY)
            self._ready.set()
            while not self._stop.is_set():
                for topic, payload in bus.poll(0.05):
                    if topic == topics.ODOMETRY:
                        state = vehicle_state_of(decode(payload, expect=Odometry))
                        bus.publish(topics.VEHICLE_STATE, state.to_wire(source="bench"))
                        self.relayed += 1
        finally:
            self._ready.set()
            bus.close()

    def __enter__(self) -> OdometryRelay:
        self._thread.start()
        self._ready.wait(10.0)
        return self

    def __exit__(
        self, _t: type[BaseException] | None, _e: BaseException | None, _tb: TracebackType | None
    ) -> None:
        self._stop.set()
        self._thread.join(5.0)
