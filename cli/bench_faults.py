"""``sensor-agent bench faults``: how fast the graph recovers from a dead or a hung stage.

On the simulated graph (``launch/sim.toml``), for every process in turn:

* **killed**: ``trials`` times, SIGKILL, then the time until its output topic carries a
  message of its new life (its sequence numbers start again), as a subscriber of that topic
  hears it: ``restart_to_output_s``. With each new life's ``startup_ms_<step>`` from its
  heartbeat (:class:`processes.runtime.Startup`): where that time went.
* **hung**: once, SIGSTOP (the process stays, silent), then the time until the launcher has
  killed it for missing heartbeats (``hang_detect_s``: the graph's ``hang_timeout_s`` plus
  the heartbeat phase) and until its new life's output (``hang_to_output_s``).

Every restart should pay the launcher's first back-off, not a doubled one: the graph runs
with ``restart_window_s`` of ``WINDOW_S`` and the trials are ``WINDOW_S`` apart, so no
restart is still in the window when the next kill comes. That pause also lets the new life's
standby spare prepare (the head's takes about 2 s on a quiet machine): a second failure
sooner than that is a cold start. Nothing else is changed.
"""

from __future__ import annotations

import os
import signal
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from agent.runtime import topics
from agent.runtime.bus import Bus
from agent.runtime.messages import Heartbeat, decode
from cli.bench_graph import GraphUnderTest, OdometryRelay, launch_variant
from processes.launcher import live_pids
from processes.runtime import Startup

ROOT = Path(__file__).resolve().parents[1]
SIM_LAUNCH = ROOT / "launch" / "sim.toml"
WINDOW_S = 4.0  # restart window of the graph under test, and the pause between trials
TIMEOUT_S = 20.0  # for any one recovery, on a loaded machine
STEADY_SEQ = 10  # messages of a life before it is killed
# Each process's output that shows it is working again.
OUTPUTS = {
    "world": topics.WORLD_TRUTH,
    "head": topics.RAW_SCAN,
    "calibration": topics.CALIBRATED_SCAN,
    "filtering": topics.FILTERED_SCAN,
    "features": topics.FEATURES,
    "tracking": topics.TRACKS,
    "planner": topics.ENVIRONMENT,
}


class _Watch:
    """One process's output and heartbeats, heard at its endpoint."""

    def __init__(self, graph: GraphUnderTest, name: str) -> None:
        self.name = name
        self.runtime = graph.runtime
        self.bus = Bus(None)
        endpoint = graph.graph.endpoints()[name]
        self.bus.subscriber.connect(endpoint)
        self.bus.subscriber.subscribe(OUTPUTS[name])
        self.bus.subscriber.subscribe(topics.HEARTBEAT)
        self.last_seq = -1
        self.beats: list[Heartbeat] = []

    def _hear(self, timeout_s: float) -> bool:
        """Listen up to ``timeout_s``; whether an output of a new life came."""
        new_life = False
        for topic, payload in self.bus.poll(timeout_s):
            msg = decode(payload)
            if topic == topics.HEARTBEAT:
                if isinstance(msg, Heartbeat) and msg.process == self.name:
                    self.beats.append(msg)
                continue
            if msg.header.seq < self.last_seq:
                new_life = True
            self.last_seq = msg.header.seq
        return new_life

    def steady(self) -> int:
        """Until the process publishes; its pid."""
        deadline = time.monotonic() + TIMEOUT_S
        # Its numbering well under way: a new life is told by its numbering starting again,
        # and must not overtake the old one's before this listener finds it.
        while self.last_seq < STEADY_SEQ:
            self._hear(0.05)
            if time.monotonic() > deadline:
                raise RuntimeError(f"{self.name} published no {OUTPUTS[self.name]}")
        pid = live_pids(self.runtime).get(self.name)
        if pid is None:
            raise RuntimeError(f"{self.name} is not running")
        return pid

    def new_life(self, started: float) -> float:
        """Seconds from ``started`` (perf_counter) to its first output of a new life."""
        deadline = time.monotonic() + TIMEOUT_S
        while not self._hear(0.005):
            if time.monotonic() > deadline:
                raise RuntimeError(f"{self.name} did not resume within {TIMEOUT_S:g} s")
        return time.perf_counter() - started

    def startup_ms(self, pid: int) -> dict[str, int]:
        """The new life's start-up steps, from its first heartbeat that has them all."""
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            for beat in self.beats:
                if beat.pid != pid:
                    continue
                steps = {
                    s: beat.counters[f"startup_ms_{s}"]
                    for s in Startup.STEPS
                    if f"startup_ms_{s}" in beat.counters
                }
                if len(steps) == len(Startup.STEPS):
                    return steps
            self._hear(0.05)
        return {}

    def close(self) -> None:
        self.bus.close()


def _summary(values: list[float]) -> dict[str, float | int]:
    a = np.asarray(values)
    return {"p50": float(np.median(a)), "max": float(a.max()), "trials": int(a.size)}


def fault_figures(trials: int, progress: Any = None) -> dict[str, Any]:
    """Restart-to-output per process over ``trials`` kills, and one hang each."""
    say = progress or (lambda _text: None)
    with tempfile.TemporaryDirectory(prefix="lepf") as tmp:
        launch_file = launch_variant(
            SIM_LAUNCH, Path(tmp), restart_window_s=str(WINDOW_S), max_restarts="100"
        )
        restart: dict[str, Any] = {}
        startup: dict[str, Any] = {}
        detect: dict[str, float] = {}
        hang_output: dict[str, float] = {}
        with GraphUnderTest(launch_file, play=None) as graph, OdometryRelay(graph):
            hang_timeout_s = graph.graph.hang_timeout_s
            for name in OUTPUTS:
                watch = _Watch(graph, name)
                try:
                    times, steps = [], []
                    for _ in range(trials):
                        pid = watch.steady()
                        killed = time.perf_counter()
                        os.kill(pid, signal.SIGKILL)
                        times.append(watch.new_life(killed))
                        new_pid = live_pids(graph.runtime).get(name)
                        if new_pid is not None and (got := watch.startup_ms(new_pid)):
                            steps.append(got)
                        time.sleep(WINDOW_S)
                    restart[name] = _summary(times)
                    startup[name] = {
                        s: float(np.median([st[s] for st in steps])) for s in Startup.STEPS
                    } if steps else {}  # fmt: skip
                    say(f"{name}: restart to output p50 {restart[name]['p50']:.2f} s")
                    pid = watch.steady()
                    stopped = time.perf_counter()
                    os.kill(pid, signal.SIGSTOP)
                    deadline = time.monotonic() + hang_timeout_s + TIMEOUT_S
                    while live_pids(graph.runtime).get(name) in (pid, None):
                        if time.monotonic() > deadline:
                            raise RuntimeError(f"the hung {name} was not restarted")
                        watch._hear(0.005)
                    detect[name] = time.perf_counter() - stopped
                    hang_output[name] = watch.new_life(stopped)
                    say(f"{name}: hang detected after {detect[name]:.2f} s")
                    time.sleep(WINDOW_S)
                except RuntimeError as exc:
                    raise RuntimeError(f"{exc}; the graph's log: {graph.log_tail(8)}") from None
                finally:
                    watch.close()
    return {
        "restart_to_output_s": restart,
        "startup_ms": startup,
        "hang_timeout_s": hang_timeout_s,
        "hang_detect_s": detect,
        "hang_to_output_s": hang_output,
    }


def print_fault_figures(f: dict[str, Any]) -> None:
    print(
        f"faults on launch/sim.toml (hang timeout {f['hang_timeout_s']:g} s); seconds, "
        "start-up steps in ms since the launcher spawned the new life"
    )
    steps = "  ".join(f"{s:>8s}" for s in Startup.STEPS)
    print(f"  {'process':12s} {'restart p50':>11s} {'max':>6s} {'hang found':>10s} "
          f"{'resumed':>8s}   {steps}")  # fmt: skip
    for name, r in f["restart_to_output_s"].items():
        st = f["startup_ms"].get(name, {})
        cells = "  ".join(f"{st[s]:8.0f}" if s in st else f"{'-':>8s}" for s in Startup.STEPS)
        print(
            f"  {name:12s} {r['p50']:11.2f} {r['max']:6.2f} "
            f"{f['hang_detect_s'][name]:10.2f} {f['hang_to_output_s'][name]:8.2f}   {cells}"
        )
