"""The launcher: starts a host's processes of a graph, supervises them, stops them cleanly.

* Each run gets a private runtime directory (mode 0700) holding the ``ipc://`` sockets and
  the resolved graph; it is listed in the user's graph registry so ``sensor-agent topics``,
  ``echo`` and ``hz`` can find the running graph, and removed on exit.
* Children are started as ``python -m MODULE --graph FILE --name NAME``. On Linux each one
  is told to receive SIGTERM if the launcher itself dies, so none is ever orphaned.
* A process that exits is restarted according to its policy (:mod:`agent.runtime.supervision`);
  when one fails for good and its ``stop_graph_on_failure`` is set, the graph stops. Any exit
  while the graph runs is a failure, status 0 included, and the launch then exits non-zero.
* A process that hangs without exiting (stopped, deadlocked, stuck in a loop) is noticed by
  its heartbeats: once it has beaten ``running``, a silence of the graph's
  ``hang_timeout_s`` (before that, ``start_timeout_s`` from its start) gets it logged,
  killed (SIGKILL: a stopped or deadlocked process ignores anything else) and restarted
  under its policy. Its ``fault`` is kept for the summary and the status line, and the
  launcher beats ``fault`` on the hung process's behalf on the control endpoint, where
  ``sensor-agent topics`` sees it; a process whose stage fails on every input beats
  ``fault`` itself.
* The launcher listens to the heartbeats. Each process's heartbeat says how many messages
  it has published per topic and when the latest went out; from these the launcher takes
  each topic's count and rate for its status line (on a terminal) and its summary, without
  receiving the topics themselves. Only while recording (``--record``) does it subscribe to
  every topic: it then stores every message to MCAP and counts them, and their gaps, as they
  arrive. The longest gap of a topic is known only then (and always for the heartbeats).
* It sleeps until a heartbeat, a child's exit (SIGCHLD, through a wake-up pipe), a restart
  or status line due, or the end of the duration: idle, it wakes about as often as the
  graph's processes beat.
* **Standby**: for every process whose ``standby`` is set (the default), the launcher keeps
  a spare: the same command with ``--standby``, started under ``SCHED_IDLE`` (it imports its
  modules, builds its stage and loads its compiled kernels on CPU nobody else wants), then
  blocked on its stdin. A restart calls the spare in (``go``: it binds, joins and runs at the
  normal policy) instead of starting an interpreter from nothing, and a new spare is started
  for the next time: restart to output then costs the back-off, the sockets and the next
  input, well under a second, instead of one to two seconds of imports and kernel loading.
  The price is one idle process per stage (about 100 MB each).
* ``pids.json`` in the runtime directory names each process's live pid and its spare's, and
  which live processes the launcher has heard beat; it is replaced whole (never half written).
* Shutdown: a ``stop`` message, then SIGINT, SIGTERM and SIGKILL, each after a timeout.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import logging
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any

from agent.errors import MessageError
from agent.runtime import topics
from agent.runtime.bus import Bus, CurveKeys, remove_ipc_file
from agent.runtime.launch import GraphSpec, ProcessSpec
from agent.runtime.messages import Header, Heartbeat, Stop, decode, stamp_ns
from agent.runtime.supervision import RestartTracker
from processes.runtime import normal_priority

log = logging.getLogger("launcher")

STOP_WAIT_S = 3.0  # after the stop message
SIGNAL_WAIT_S = 2.0  # after SIGINT, and again after SIGTERM
RATE_WINDOW = 200  # arrivals a topic's rate is measured over, at most
STATUS_S = 0.5  # the status line's period, on a terminal
MAX_WAIT_S = 1.0  # a backstop: heartbeats, SIGCHLD and deadlines end a wait sooner
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


PIDS_FILE = "pids.json"


def _read_pids(runtime_dir: str | Path) -> Any:
    """The launcher's ``pids.json`` as it last wrote it; None if there is none to read."""
    try:
        return json.loads((Path(runtime_dir) / PIDS_FILE).read_text())
    except (OSError, ValueError):
        return None


def live_pids(runtime_dir: str | Path) -> dict[str, int]:
    """Each process's live pid by name (not its standby's), as the launcher last wrote them."""
    try:
        return {str(name): int(pid) for name, pid in _read_pids(runtime_dir)["active"].items()}
    except (ValueError, KeyError, TypeError, AttributeError):
        return {}


def beating(runtime_dir: str | Path) -> set[str]:
    """The processes whose live process the launcher has heard beat ``running`` or
    ``fault``, as it last wrote them (empty if it has not)."""
    try:
        return {str(name) for name in _read_pids(runtime_dir)["beating"]}
    except (KeyError, TypeError):
        return set()


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

    def summary(self) -> dict[str, Any]:
        return {"count": self.count, "rate_hz": round(self.rate_hz(), 3),
                "max_gap_s": round(self.max_gap_s, 4), "counted_from": "bus"}  # fmt: skip


@dataclass
class PublishedStats:
    """A topic's count and rate from what its publisher says in its heartbeats.

    Each heartbeat gives, per topic, the messages published so far and when the latest went
    out (``published_<topic>``, ``last_published_ns_<topic>``). ``rate_hz`` keeps
    :class:`TopicStats`' definition: the mean rate over the later half of the messages (at
    most the last ``RATE_WINDOW``), here between the publication times the heartbeats report,
    the window's start moved to the first heartbeat inside it. A restarted publisher counts
    from zero again: its earlier lives' counts are carried over, less what a killed one
    published after its last heartbeat.
    """

    count: int = 0
    # (messages so far, time of the latest in s), one per heartbeat that brought news
    samples: deque[tuple[int, float]] = field(default_factory=deque)
    _lives: dict[str, tuple[int, int, int]] = field(default_factory=dict)  # pid, base, count

    def see(self, process: str, pid: int, published: int, last_ns: int) -> None:
        life = self._lives.get(process)
        base = 0 if life is None else life[1] if life[0] == pid else life[1] + life[2]
        self._lives[process] = (pid, base, published)
        total = sum(b + n for _, b, n in self._lives.values())
        if total == self.count:
            return  # nothing published since the last heartbeat
        self.count = total
        self.samples.append((total, last_ns * 1e-9))
        while self.samples and self.samples[0][0] <= total - RATE_WINDOW:
            self.samples.popleft()

    def rate_hz(self) -> float:
        if len(self.samples) < 2:
            return 0.0
        first = self.count - min(RATE_WINDOW, (self.count + 1) // 2) + 1
        start = next(s for s in self.samples if s[0] >= first)
        end = self.samples[-1]
        span = end[1] - start[1]
        return (end[0] - start[0]) / span if span > 0 and end[0] > start[0] else 0.0

    def summary(self) -> dict[str, Any]:
        return {"count": self.count, "rate_hz": round(self.rate_hz(), 3),
                "max_gap_s": None, "counted_from": "heartbeats"}  # fmt: skip


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
    started_at: float = 0.0  # monotonic, when last started
    beat_at: float | None = None  # monotonic, when a "running" or "fault" beat last came
    fault: str = ""  # the latest fault: why it was killed, or that its stage is failing
    hangs: int = 0
    kill_cause: str = ""  # set when the launcher killed it, until its exit is seen
    spare: subprocess.Popen[bytes] | None = None  # its standby, if any
    from_standby: int = 0  # restarts that called the spare in


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
        self.pids_file = self.runtime / PIDS_FILE
        self.graph_file.write_text(self.graph.to_json())
        self.children = {p.name: Child(p, RestartTracker(p)) for p in self.graph.on_host(host)}
        self.stats: dict[str, TopicStats] = {}  # topics heard on the bus
        self.published: dict[str, PublishedStats] = {}  # topics known from heartbeats
        self.status_line = sys.stderr.isatty() if status_line is None else status_line
        self.recorder = recorder
        self.stop_reason = ""
        self.failed = False
        self._stop_requested = False
        self._child_exited = False
        keys = CurveKeys.load(self.graph.keys_dir) if self.graph.keys_dir else None
        self.bus = Bus(self.graph.control_endpoint, keys)
        for endpoint in self.graph.endpoints().values():
            self.bus.subscriber.connect(endpoint)
        if recorder is not None:
            self.bus.subscriber.subscribe_all()
        else:
            self.bus.subscriber.subscribe(topics.HEARTBEAT)
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
    def _command(self, spec: ProcessSpec) -> list[str]:
        graph, name = str(self.graph_file), spec.name
        return [sys.executable, "-m", spec.module, "--graph", graph, "--name", name]

    def _start(self, child: Child, with_spare: bool = True) -> None:
        """Start a process: call its spare in if it has a live one, else a new interpreter;
        then (``with_spare``) a new spare for the next time."""
        spare, child.spare = child.spare, None
        child.popen = None
        if spare is not None and spare.poll() is None and spare.stdin is not None:
            normal_priority(spare.pid)  # before "go": an idle spare may not run to read it
            try:
                spare.stdin.write(f"go {time.time_ns()}\n".encode())
                spare.stdin.close()
                child.popen = spare
                child.from_standby += 1
            except OSError:  # it died just now
                spare.kill()
                spare.wait()
        if child.popen is None:
            cmd = [*self._command(child.spec), "--spawned-ns", str(time.time_ns())]
            child.popen = subprocess.Popen(cmd, preexec_fn=_die_with_parent)
        how = "its standby" if child.popen is spare else "new"
        child.state, child.exit_code, child.restart_at = "running", None, None
        child.started_at, child.beat_at, child.kill_cause = time.monotonic(), None, ""
        log.info("started %s (pid %d, %s)", child.spec.name, child.popen.pid, how)
        if with_spare:
            self._start_spare(child)
        self._write_pids()

    def _start_spare(self, child: Child) -> None:
        if not child.spec.standby or child.spare is not None:
            return
        child.spare = subprocess.Popen(
            [*self._command(child.spec), "--standby"],
            stdin=subprocess.PIPE,
            preexec_fn=_die_with_parent,
        )
        # Idle only once it runs the interpreter: an idle child on a busy machine might not
        # get as far as exec for seconds, and Popen waits for that.
        if hasattr(os, "sched_setscheduler"):
            with contextlib.suppress(OSError):
                os.sched_setscheduler(child.spare.pid, os.SCHED_IDLE, os.sched_param(0))

    def _write_pids(self) -> None:
        pids = {
            "active": {n: c.popen.pid for n, c in self.children.items() if c.popen is not None},
            "standby": {n: c.spare.pid for n, c in self.children.items() if c.spare is not None},
            # Whose live process the launcher has heard beat: from then on its hang limit
            # is hang_timeout_s after its last beat, before it start_timeout_s after start.
            "beating": sorted(n for n, c in self.children.items() if c.beat_at is not None),
        }
        # Replaced whole, never truncated in place: a reader (``live_pids``, the tests, a
        # tool) must not find it half written.
        partial = self.pids_file.with_name(self.pids_file.name + ".partial")
        partial.write_text(json.dumps(pids))
        os.replace(partial, self.pids_file)

    def _stop_spares(self) -> None:
        """End every spare: EOF on its stdin (it exits), then SIGKILL to be sure."""
        spares = [c.spare for c in self.children.values() if c.spare is not None]
        for spare in spares:
            with contextlib.suppress(OSError):
                if spare.stdin is not None:
                    spare.stdin.close()
            spare.kill()
        for spare in spares:
            spare.wait()
        for child in self.children.values():
            child.spare = None

    def _check_children(self, now_s: float) -> None:
        for child in self.children.values():
            if child.spare is not None and child.spare.poll() is not None:
                log.warning(
                    "%s's standby exited with %d; the next restart starts a new process",
                    child.spec.name,
                    child.spare.returncode,
                )
                child.spare = None
                self._write_pids()
            if child.popen is not None and child.state == "running":
                code = child.popen.poll()
                if code is None:
                    continue
                child.exit_code = code
                child.history.append(code)
                decision = child.tracker.on_exit(now_s, code, child.kill_cause)
                log.warning("%s exited with %d: %s", child.spec.name, code, decision.reason)
                if decision.action == "restart":
                    child.state, child.restart_at = "restarting", now_s + decision.delay_s
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

    def _check_hung(self, now: float) -> None:
        """Kill every running process whose heartbeats stopped (see the module docstring)."""
        for child in self.children.values():
            if child.state != "running" or child.popen is None or child.kill_cause:
                continue
            last, limit, since = self._silence_allowed(child)
            silent = now - last
            if silent < limit:
                continue
            child.hangs += 1
            child.kill_cause = child.fault = (
                f"hung: no heartbeat for {silent:.1f} s (limit {limit:g} s since its {since})"
            )
            log.error("%s (pid %d) %s; killing it", child.spec.name, child.popen.pid, child.fault)
            child.popen.kill()
            self._beat_fault(child)
            self._child_exited = True  # look at its exit soon, without waiting for SIGCHLD

    def _beat_fault(self, child: Child) -> None:
        """A ``fault`` heartbeat on a hung process's behalf, for listeners such as ``topics``."""
        assert child.popen is not None
        beat = Heartbeat(
            header=Header(stamp_ns=stamp_ns(time.time()), source="launcher"),
            process=child.spec.name,
            pid=child.popen.pid,
            state="fault",
            counters={"hangs": child.hangs, "restarts": child.tracker.restarts},
        )
        self.bus.publish(topics.HEARTBEAT, beat.to_wire())

    def _silence_allowed(self, child: Child) -> tuple[float, float, str]:
        """Since when (monotonic) a process has been silent, how long it may be, and since
        what: its last beat once it has beaten ``running``, else its start."""
        if child.beat_at is None:
            return child.started_at, self.graph.start_timeout_s, "start"
        return child.beat_at, self.graph.hang_timeout_s, "beat"

    def _next_hang_check(self) -> float:
        """When (monotonic) the next running process would count as hung."""
        due = math.inf
        for child in self.children.values():
            if child.state == "running" and not child.kill_cause:
                last, limit, _ = self._silence_allowed(child)
                due = min(due, last + limit)
        return due

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
                if isinstance(beat, Heartbeat):
                    self._see_heartbeat(beat)

    def _see_heartbeat(self, beat: Heartbeat) -> None:
        child = self.children.get(beat.process)
        if child is not None and child.popen is not None and beat.pid == child.popen.pid:
            child.last_heartbeat = beat
            if beat.state in ("running", "fault"):
                first = child.beat_at is None
                child.beat_at = time.monotonic()
                if first:
                    self._write_pids()
            if beat.state == "fault":
                child.fault = "its stage fails on every input (see its log)"
        counters = beat.counters
        for key, count in counters.items():
            if key.startswith("published_"):
                topic = key[len("published_") :]
                last_ns = counters.get(f"last_published_ns_{topic}")
                if last_ns is not None:
                    stats = self.published.setdefault(topic, PublishedStats())
                    stats.see(beat.process, beat.pid, count, last_ns)

    def topic_stats(self, topic: str) -> TopicStats | PublishedStats | None:
        """What is known of a topic: heard on the bus if the launcher listens to it (every
        topic while recording, else the heartbeats), otherwise from its publisher's beats."""
        if self.recorder is not None or topic in self.stats:
            return self.stats.get(topic)
        return self.published.get(topic)

    def status(self) -> str:
        parts = []
        for name, child in self.children.items():
            beat = child.last_heartbeat
            rates = [self.topic_stats(t) for t in child.spec.outputs]
            rate = max((r.rate_hz() for r in rates if r is not None), default=0.0)
            sent = beat.counters.get("published", 0) if beat else 0
            state = child.state
            if beat is not None and beat.state == "fault" and state == "running":
                state = "fault"
            if child.hangs:
                state += f" ({child.hangs} hung)"
            parts.append(f"{name}: {state} r{child.tracker.restarts} {rate:5.1f} Hz ({sent} sent)")
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
        self._stop_spares()
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
    @contextmanager
    def _signals(self) -> Iterator[None]:
        """SIGINT and SIGTERM stop the graph; SIGCHLD marks a child to look at. Each one also
        ends the current wait at once, through a wake-up pipe the bus polls."""

        def on_stop(signum: int, _frame: FrameType | None) -> None:
            self.request_stop(f"signal {signal.Signals(signum).name}")

        def on_child(_signum: int, _frame: FrameType | None) -> None:
            self._child_exited = True

        handlers = {signal.SIGINT: on_stop, signal.SIGTERM: on_stop, signal.SIGCHLD: on_child}
        old = {s: signal.signal(s, h) for s, h in handlers.items()}
        wake_read, wake_write = os.pipe()
        os.set_blocking(wake_read, False)
        os.set_blocking(wake_write, False)
        old_wakeup = signal.set_wakeup_fd(wake_write, warn_on_full_buffer=False)
        self.bus.wake_on(wake_read)
        try:
            yield
        finally:
            signal.set_wakeup_fd(old_wakeup)
            for s, handler in old.items():
                signal.signal(s, handler)
            os.close(wake_read)
            os.close(wake_write)

    def run(self, duration_s: float | None = None) -> int:
        started = time.monotonic()
        end = None if duration_s is None else started + duration_s
        next_status = next_check = started
        try:
            with self._signals():
                for child in self.children.values():
                    self._start(child, with_spare=False)
                for child in self.children.values():  # once the graph itself is on its way
                    self._start_spare(child)
                self._write_pids()
                while not self._stop_requested:
                    now = time.monotonic()
                    if end is not None and now >= end:
                        self.request_stop(f"duration of {duration_s:g} s reached")
                        break
                    if self.status_line and now >= next_status:
                        next_status = now + STATUS_S
                        line = "\r" + self.status()[:200].ljust(120)
                        print(line, end="", file=sys.stderr, flush=True)
                    self._monitor(self._wait_s(now, end, next_status))
                    # The children are looked at when one exited, a restart is due, or after
                    # MAX_WAIT_S as a backstop; not after every heartbeat.
                    now = time.monotonic()
                    if now >= self._next_hang_check():
                        self._check_hung(now)
                    if self._child_exited or now >= next_check or self._restart_due():
                        self._child_exited = False
                        next_check = now + MAX_WAIT_S
                        self._check_children(time.time())
                self._shutdown()
        finally:
            if self.status_line:
                print(file=sys.stderr)
            self.close()
        clean = not self.failed and all(
            c.exit_code == 0 and c.state != "failed" for c in self.children.values()
        )
        return 0 if clean else 1

    def _restart_times(self) -> list[float]:
        return [
            c.restart_at
            for c in self.children.values()
            if c.state == "restarting" and c.restart_at is not None
        ]

    def _restart_due(self) -> bool:
        return any(t <= time.time() for t in self._restart_times())

    def _wait_s(self, now: float, end: float | None, next_status: float) -> float:
        """How long the launcher may sleep: until the next thing it must do itself."""
        due = [now + MAX_WAIT_S, self._next_hang_check()]
        if end is not None:
            due.append(end)
        if self.status_line:
            due.append(next_status)
        wall = time.time()
        due += [now + t - wall for t in self._restart_times()]
        return max(0.0, min(due) - now)

    def summary(self) -> dict[str, Any]:
        return {
            "graph": self.graph.name, "stop_reason": self.stop_reason, "failed": self.failed,
            "processes": {
                name: {"exit_code": c.exit_code, "restarts": c.tracker.restarts,
                       "state": c.state, "exit_history": c.history,
                       "hangs": c.hangs, "fault": c.fault, "from_standby": c.from_standby,
                       "counters": c.last_heartbeat.counters if c.last_heartbeat else {}}
                for name, c in self.children.items()},
            "topics": {t: stats.summary() for t in sorted({*self.stats, *self.published})
                       if (stats := self.topic_stats(t)) is not None and stats.count},
        }  # fmt: skip

    def close(self) -> None:
        self._stop_spares()
        self.bus.close()
        self.pids_file.unlink(missing_ok=True)
        for child in self.children.values():  # a killed process could not remove its own
            remove_ipc_file(child.spec.endpoint)
        if self.recorder is not None:
            self.recorder.close()
        self._registry_entry.unlink(missing_ok=True)
        if self._own_runtime:
            shutil.rmtree(self.runtime, ignore_errors=True)
