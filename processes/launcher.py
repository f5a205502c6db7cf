"""The launcher: starts a host's processes of a graph, supervises them, stops them cleanly.

* Each run gets a private runtime directory (mode 0700) holding the ``ipc://`` sockets and
  the resolved graph; it is listed in the user's graph registry so ``sensor-agent topics``,
  ``echo`` and ``hz`` can find the running graph, and removed on exit.
* Children are started as ``python -m MODULE --graph FILE --name NAME``. On Linux each one
  is told to receive SIGTERM if the launcher itself dies, so none is ever orphaned.
* A process that exits is restarted according to its policy (:mod:`agent.runtime.supervision`);
  when one fails for good and its ``stop_graph_on_failure`` is set, the graph stops.
* The launcher subscribes to every topic: it counts messages and gaps per topic, reads the
  heartbeats, shows a status line on a terminal, and can record everything to MCAP.
* Shutdown: a ``stop`` message, then SIGINT, SIGTERM and SIGKILL, each after a timeout.
"""

from __future__ import annotations

import ctypes
import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any

from agent.errors import MessageError
from agent.runtime import topics
from agent.runtime.bus import Bus, CurveKeys
from agent.runtime.launch import GraphSpec, ProcessSpec
from agent.runtime.messages import Header, Heartbeat, Stop, decode, stamp_ns
from agent.runtime.supervision import RestartTracker

log = logging.getLogger("launcher")

STOP_WAIT_S = 3.0  # after the stop message
SIGNAL_WAIT_S = 2.0  # after SIGINT, and again after SIGTERM
RATE_WINDOW = 200  # arrivals a topic's rate is measured over, at most
_PR_SET_PDEATHSIG = 1


def registry_dir() -> Path:
    """Where running graphs are listed (one JSON file each), private to the user."""
    base = Path(os.environ.get("XDG_RUNTIME_DIR") or tempfile.gettempdir())
    d = base / f"lep-agent-{os.getuid()}"
    d.mkdir(mode=0o700, exist_ok=True)
    return d


def running_graphs() -> list[dict[str, Any]]:
    """The graphs whose launcher is still alive, newest first."""
    found = []
    for entry in registry_dir().glob("*.json"):
        try:
            info = json.loads(entry.read_text())
            os.kill(int(info["pid"]), 0)
        except (OSError, ValueError, KeyError):
            continue
        found.append(info)
    return sorted(found, key=lambda i: i.get("started", 0), reverse=True)


def process_ids(runtime_dir: str | Path) -> list[int]:
    """Pids of the processes started for the graph with this runtime directory (Linux)."""
    marker = str(Path(runtime_dir) / "graph.json").encode()
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if marker in (entry / "cmdline").read_bytes():
                    pids.append(int(entry.name))
            except OSError:
                continue
    return pids


def _die_with_parent() -> None:  # runs in the child before exec
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):  # not Linux: rely on the stop sequence alone
        pass


@dataclass
class TopicStats:
    """What the launcher saw of one topic: count, recent rate and the longest silence.

    ``rate_hz`` is the mean rate over the later half of the arrivals (at most the last
    ``RATE_WINDOW``), the rate a topic settles at. The mean over the whole run is not used:
    scans queued while the processes start (imports and compiled kernels loading on shared
    cores) arrive in a burst, and in a run of a few seconds that burst moved the whole-run
    mean of ``filtered_scan`` by up to 50 % (15 Hz for a 10 Hz topic). A mean, not a median
    interval, so a topic several processes publish (``heartbeat``) gets its total rate.
    """

    count: int = 0
    max_gap_s: float = 0.0
    bad: int = 0
    arrivals_s: deque[float] = field(default_factory=lambda: deque(maxlen=RATE_WINDOW))

    def see(self, now_s: float) -> None:
        if self.arrivals_s:
            self.max_gap_s = max(self.max_gap_s, now_s - self.arrivals_s[-1])
        self.arrivals_s.append(now_s)
        self.count += 1

    def rate_hz(self) -> float:
        recent = min(len(self.arrivals_s), (self.count + 1) // 2)
        if recent < 2:
            return 0.0
        span = self.arrivals_s[-1] - self.arrivals_s[-recent]
        return (recent - 1) / span if span > 0 else 0.0


@dataclass
class Child:
    spec: ProcessSpec
    tracker: RestartTracker
    popen: subprocess.Popen[bytes] | None = None
    state: str = "starting"
    exit_code: int | None = None
    restart_at: float | None = None
    last_heartbeat: Heartbeat | None = None
    history: list[int] = field(default_factory=list)


class Launcher:
    """Runs one host's share of a graph until told to stop, the duration ends, or it fails."""

    def __init__(
        self,
        graph: GraphSpec,
        host: str | None = None,
        runtime_dir: str | Path | None = None,
        status_line: bool | None = None,
        recorder: Any = None,
    ) -> None:
        base = Path(os.environ.get("XDG_RUNTIME_DIR") or tempfile.gettempdir())
        if runtime_dir is None:
            self.runtime = Path(tempfile.mkdtemp(prefix=f"lep-{graph.name}-", dir=base))
            self._own_runtime = True
        else:
            self.runtime = Path(runtime_dir)
            self.runtime.mkdir(mode=0o700, parents=True, exist_ok=True)
            self._own_runtime = False
        self.runtime.chmod(0o700)
        self.graph = graph.resolve(self.runtime)
        self.graph_file = self.runtime / "graph.json"
        self.graph_file.write_text(self.graph.to_json())
        self.children = {p.name: Child(p, RestartTracker(p)) for p in self.graph.on_host(host)}
        self.stats: dict[str, TopicStats] = {}
        self.status_line = sys.stderr.isatty() if status_line is None else status_line
        self.recorder = recorder
        self.stop_reason = ""
        self.failed = False
        self._stop_requested = False
        keys = CurveKeys.load(self.graph.keys_dir) if self.graph.keys_dir else None
        self.bus = Bus(self.graph.control_endpoint, keys)
        for endpoint in self.graph.endpoints().values():
            self.bus.subscriber.connect(endpoint)
        self.bus.subscriber.subscribe_all()
        self._registry_entry = registry_dir() / f"{self.graph.name}-{os.getpid()}.json"
        self._registry_entry.write_text(
            json.dumps(
                {
                    "graph": self.graph.name,
                    "pid": os.getpid(),
                    "started": time.time(),
                    "runtime_dir": str(self.runtime),
                    "graph_file": str(self.graph_file),
                    "launch_file": self.graph.path,
                }
            )
        )

    # --------------------------------------------------------------------------- children
    def _start(self, child: Child) -> None:
        cmd = [
            sys.executable,
            "-m",
            child.spec.module,
            "--graph",
            str(self.graph_file),
            "--name",
            child.spec.name,
        ]
        child.popen = subprocess.Popen(cmd, preexec_fn=_die_with_parent)
        child.state, child.exit_code, child.restart_at = "running", None, None
        log.info("started %s (pid %d)", child.spec.name, child.popen.pid)

    def _check_children(self, now_s: float) -> None:
        for child in self.children.values():
            if child.popen is not None and child.state == "running":
                code = child.popen.poll()
                if code is None:
                    continue
                child.exit_code = code
                child.history.append(code)
                decision = child.tracker.on_exit(now_s, code)
                log.warning("%s exited with %d: %s", child.spec.name, code, decision.reason)
                if decision.action == "restart":
                    child.state, child.restart_at = "restarting", now_s + decision.delay_s
                elif decision.action == "done":
                    child.state = "exited"
                else:
                    child.state = "failed"
                    if child.spec.stop_graph_on_failure:
                        self.failed = True
                        self.request_stop(f"{child.spec.name} failed: {decision.reason}")
            elif (
                child.state == "restarting"
                and child.restart_at is not None
                and now_s >= child.restart_at
            ):
                self._start(child)

    # ---------------------------------------------------------------------------- monitor
    def _monitor(self, timeout_s: float) -> None:
        for topic, payload in self.bus.poll(timeout_s):
            now = time.time()
            stats = self.stats.setdefault(topic or "<malformed>", TopicStats())
            stats.see(now)
            if self.recorder is not None:
                self.recorder.write(topic, payload, time.time_ns())
            if topic == topics.HEARTBEAT:
                try:
                    beat = decode(payload, expect=Heartbeat)
                except MessageError:
                    stats.bad += 1
                    continue
                if isinstance(beat, Heartbeat) and beat.process in self.children:
                    self.children[beat.process].last_heartbeat = beat

    def status(self) -> str:
        parts = []
        for name, child in self.children.items():
            beat = child.last_heartbeat
            rate = max(
                (self.stats[t].rate_hz() for t in child.spec.outputs if t in self.stats),
                default=0.0,
            )
            sent = beat.counters.get("published", 0) if beat else 0
            parts.append(
                f"{name}: {child.state} r{child.tracker.restarts} {rate:5.1f} Hz ({sent} sent)"
            )
        return " | ".join(parts)

    # ------------------------------------------------------------------------------- stop
    def request_stop(self, reason: str) -> None:
        if not self._stop_requested:
            self._stop_requested = True
            self.stop_reason = reason
            log.info("stopping: %s", reason)

    def _shutdown(self) -> None:
        stop = Stop(
            header=Header(stamp_ns=stamp_ns(time.time()), source="launcher"),
            reason=self.stop_reason,
        )
        for child in self.children.values():
            if child.state in ("restarting", "starting"):
                child.state = "exited"
        self.bus.publish(topics.STOP, stop.to_wire())
        live = [c for c in self.children.values() if c.popen and c.popen.poll() is None]
        for sig, wait_s in (
            (None, STOP_WAIT_S),
            (signal.SIGINT, SIGNAL_WAIT_S),
            (signal.SIGTERM, SIGNAL_WAIT_S),
            (signal.SIGKILL, SIGNAL_WAIT_S),
        ):
            live = [c for c in live if c.popen is not None and c.popen.poll() is None]
            if not live:
                break
            if sig is not None:
                log.warning("sending %s to %s", sig.name, ", ".join(c.spec.name for c in live))
                for c in live:
                    if c.popen is not None:
                        c.popen.send_signal(sig)
            deadline = time.monotonic() + wait_s
            while time.monotonic() < deadline and any(
                c.popen is not None and c.popen.poll() is None for c in live
            ):
                self._monitor(0.05)
                if sig is None and time.monotonic() > deadline - wait_s + 0.5:
                    self.bus.publish(topics.STOP, stop.to_wire())  # for late subscribers
        for child in self.children.values():
            if child.popen is not None:
                child.popen.wait()
                if child.state == "running":
                    child.exit_code = child.popen.returncode
                    child.state = "exited"

    # -------------------------------------------------------------------------------- run
    def run(self, duration_s: float | None = None) -> int:
        def on_signal(signum: int, _frame: FrameType | None) -> None:
            self.request_stop(f"signal {signal.Signals(signum).name}")

        old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        started = time.monotonic()
        last_status = 0.0
        try:
            for child in self.children.values():
                self._start(child)
            while not self._stop_requested:
                self._monitor(0.05)
                self._check_children(time.time())
                if duration_s is not None and time.monotonic() - started >= duration_s:
                    self.request_stop(f"duration of {duration_s:g} s reached")
                if self.status_line and time.monotonic() - last_status > 0.5:
                    last_status = time.monotonic()
                    print(
                        "\r" + self.status()[:200].ljust(120), end="", file=sys.stderr, flush=True
                    )
            self._shutdown()
        finally:
            for s, handler in old.items():
                signal.signal(s, handler)
            if self.status_line:
                print(file=sys.stderr)
            self.close()
        clean = not self.failed and all(c.exit_code == 0 for c in self.children.values())
        return 0 if clean else 1

    def summary(self) -> dict[str, Any]:
        return {
            "graph": self.graph.name, "stop_reason": self.stop_reason, "failed": self.failed,
            "processes": {
                name: {"exit_code": c.exit_code, "restarts": c.tracker.restarts,
                       "state": c.state, "exit_history": c.history,
                       "counters": c.last_heartbeat.counters if c.last_heartbeat else {}}
                for name, c in self.children.items()},
            "topics": {
                t: {"count": s.count, "rate_hz": round(s.rate_hz(), 3),
                    "max_gap_s": round(s.max_gap_s, 4)}
                for t, s in sorted(self.stats.items())},
        }  # fmt: skip

    def close(self) -> None:
        self.bus.close()
        if self.recorder is not None:
            self.recorder.close()
        self._registry_entry.unlink(missing_ok=True)
        if self._own_runtime:
            shutil.rmtree(self.runtime, ignore_errors=True)
