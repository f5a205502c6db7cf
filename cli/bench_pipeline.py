"""The agent's pipeline (the stages of ``launch/agent.toml``), saturated and at 10 Hz.

Both ways of running it do the same work per scan: the same raw scans, cycled; the same
stages, built from the same launch file; every message (the raw scan, each stage's output)
encoded to its wire bytes and decoded with full validation once.

* In one process: the lock-step runner, which encodes and decodes every message it passes on.
* As processes: the real launcher and sockets; the bench plays the head (it encodes each
  raw scan when it sends it) and the final consumer (it decodes each output).

Saturated throughput is closed-loop: the bench keeps ``IN_FLIGHT`` scans outstanding, so
every stage has a backlog, as when a head outpaces the graph (each process then works
through its queue back to back, with its caches warm: about 20 % less CPU per scan than with
a handful in flight), yet no queue reaches ZeroMQ's limit (``agent.runtime.bus.HWM``), where
scans would be dropped. The graph runs with ``backlog = "all"``: by default a process that
finds several scans queued handles only the newest (a live graph wants data of now), and the
saturated run is exactly that case. The processes also run in parallel on the cores there
are; the CPU per scan, summed over every process that works on it (the bench's encoding and
decoding included, the launcher apart), is the figure that shows what running as processes
costs.
Both runs first pass ``WARM_UP_SCANS`` untimed, so loading the compiled kernels (a third of
a second per process, when its stage starts) and first-use costs fall outside the timing.

Latency at 10 Hz: each raw scan is stamped so that its last sample is "now" when it is sent,
and the figure is the time from then until its last stage's output has been received and
decoded, by the same clock.
"""

from __future__ import annotations

import dataclasses
import re
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agent.runtime import topics
from agent.runtime.launch import GraphSpec, load_launch
from agent.runtime.messages import Features, Message, RawScan, decode, stamp_ns
from agent.sensor.params import simulated_head
from cli.bench_graph import ROOT, GraphUnderTest, launch_variant, process_cpu_s
from cli.bench_messages import standing_vehicle_state
from processes.runtime import lockstep_graph

# Scans outstanding while saturated. Each is two messages on the bench's socket (its vehicle
# state and the raw scan), and tracking and the planner queue three per scan (state, filtered
# scan, features or tracks): 20 keep every queue under ZeroMQ's limit (agent.runtime.bus.HWM,
# 100), where messages would be dropped, with room for the heartbeats and for scans of the
# warm-up still on their way (30 left none: on a loaded machine 3 of 50 scans were lost).
IN_FLIGHT = 20
WARM_UP_SCANS = 50
REPLY_TIMEOUT_S = 30.0  # for a scan's output while the graph starts on a shared machine
LATE_S = 2.0  # how long the bench waits for the last outputs at 10 Hz
# Saturated scans end at T0_S + seq x SPACING_S: stamps always increase, and the IN_FLIGHT
# scans outstanding span under a second of their own time, within the 3 s of vehicle states that
# filtering and tracking hold (a sweep period apart, they would span 3 s, and the states
# sent ahead of the last would push out those of the first).
T0_S = 1000.0
SPACING_S = 0.025
OUTPUT = topics.ENVIRONMENT  # the pipeline's output, one per scan: a scan is done when it is out


@dataclass
class Throughput:
    scans: int
    seconds: float
    cpu_s: dict[str, float]  # CPU used meanwhile, per process (and "bench")

    @property
    def scans_per_s(self) -> float:
        return self.scans / self.seconds


def percentiles_ms(latencies_s: list[float], of: int) -> dict[str, Any]:
    lat = 1e3 * np.asarray(latencies_s, dtype=np.float64)
    return {
        "p50": float(np.percentile(lat, 50)) if lat.size else None,
        "p99": float(np.percentile(lat, 99)) if lat.size else None,
        "max": float(lat.max()) if lat.size else None,
        "scans": int(lat.size),
        "of": of,
    }


def _ending_now(scan: RawScan, now_s: float, seq: int) -> RawScan:
    """``scan`` moved in time so that its last sample is at ``now_s``, renumbered ``seq``."""
    return dataclasses.replace(
        scan,
        header=dataclasses.replace(scan.header, stamp_ns=stamp_ns(now_s), seq=seq),
        time_s=scan.time_s - scan.time_s[-1] + now_s,
        sweep_index=seq,
    )


# ------------------------------------------------------------------------------ in one process
def in_process_figures(
    graph: GraphSpec, scans: list[RawScan], count: int, latency_scans: int
) -> dict[str, Any]:
    """Saturated scans per second, CPU per scan and latency at 10 Hz, in the lock-step runner."""
    runner = lockstep_graph(graph)
    outputs: dict[str, list[float]] = {t: [] for t in (OUTPUT, topics.FEATURES)}

    def seen(_t: float, topic: str, _msg: Message) -> None:
        if topic in outputs:
            outputs[topic].append(time.perf_counter())

    def inject(scan: RawScan) -> None:
        state = standing_vehicle_state(scan.header.stamp_ns, scan.header.seq)
        runner.inject(topics.VEHICLE_STATE, state, source="vehicle")
        runner.inject(topics.RAW_SCAN, scan, source="head")

    runner.observe(seen)
    period = simulated_head().sweep_period_s
    seq = 0
    for _ in range(WARM_UP_SCANS):
        inject(_ending_now(scans[seq % len(scans)], T0_S + seq * SPACING_S, seq))
        seq += 1
    restamped = [_ending_now(scans[(seq + i) % len(scans)], T0_S + (seq + i) * SPACING_S, seq + i)
                 for i in range(count)]  # fmt: skip
    seq += count
    outputs[OUTPUT].clear()
    cpu_started = time.process_time()
    started = time.perf_counter()
    for scan in restamped:
        inject(scan)
    elapsed = time.perf_counter() - started
    cpu_s = time.process_time() - cpu_started
    if len(outputs[OUTPUT]) < count:
        raise RuntimeError(
            f"in-process pipeline produced {len(outputs[OUTPUT])} of {count} {OUTPUT}"
        )
    # At 10 Hz: one scan every sweep period, caches as cold as they are between scans.
    latencies: dict[str, list[float]] = {t: [] for t in outputs}
    next_send = time.perf_counter()
    for _ in range(latency_scans):
        time.sleep(max(0.0, next_send - time.perf_counter()))
        for got in outputs.values():
            got.clear()
        sent = time.perf_counter()
        inject(_ending_now(scans[seq % len(scans)], time.time(), seq))
        seq += 1
        for topic, got in outputs.items():
            if got:
                latencies[topic].append(got[-1] - sent)
        next_send += period
    return {
        "scans_per_s": count / elapsed,
        "cpu_ms_per_scan": 1e3 * cpu_s / count,
        "latency_ms": percentiles_ms(latencies[topics.FEATURES], latency_scans),
        "latency_ms_to_environment": percentiles_ms(latencies[OUTPUT], latency_scans),
    }


# ------------------------------------------------------------------------------- as processes
class _Driver:
    """The bench's side of the agent graph: sends vehicle states and raw scans, receives and
    decodes the features and the environment vectors."""

    def __init__(self, graph: GraphUnderTest, scans: list[RawScan]) -> None:
        self.graph = graph
        self.bus = graph.listen()
        self.scans = scans
        self.seq = 0
        self.types = {t: topics.message_type(t) for t in (OUTPUT, topics.FEATURES)}
        self.period_s = simulated_head().sweep_period_s
        self._features: set[int] = set()  # stamps of features whose vector is still to come
        self._vectors: set[int] = set()  # stamps of vectors whose features are still to come

    def send(self, now_s: float | None = None) -> None:
        """The next scan, ending at ``now_s`` (default: ``SPACING_S`` after the last one),
        after the vehicle state of that time."""
        ends = T0_S + self.seq * SPACING_S if now_s is None else now_s
        scan = _ending_now(self.scans[self.seq % len(self.scans)], ends, self.seq)
        state = standing_vehicle_state(scan.header.stamp_ns, self.seq)
        self.bus.publish(topics.VEHICLE_STATE, state.to_wire(source="vehicle"))
        self.bus.publish(topics.RAW_SCAN, scan.to_wire(source="head"))
        self.seq += 1

    def receive(self, timeout_s: float) -> list[tuple[float, str, Message]]:
        """Outputs that arrive within ``timeout_s`` (maybe none), with their receipt time."""
        got = []
        for topic, payload in self.bus.poll(timeout_s):
            if topic in self.types:
                got.append((time.perf_counter(), topic, decode(payload, expect=self.types[topic])))
        return got

    def outputs(self, timeout_s: float) -> int:
        """Scans through the graph within ``timeout_s``: environment vectors whose stamp is
        that of features received (the planner's vectors with no scan behind them, which it
        sends while no tracks arrive, do not count)."""
        done = 0
        for _, topic, msg in self.receive(timeout_s):
            stamp = msg.header.stamp_ns
            mine, other = (
                (self._features, self._vectors) if topic == topics.FEATURES
                else (self._vectors, self._features)
            )  # fmt: skip
            if stamp in other:
                other.discard(stamp)
                done += 1
            else:
                mine.add(stamp)
        return done

    def first_output(self) -> None:
        """Send scans until an output comes back: the bench's subscription is in place, and
        ZeroMQ delivers everything after it (ipc, queues below their limit)."""
        deadline = time.monotonic() + REPLY_TIMEOUT_S
        while True:
            if time.monotonic() > deadline or self.graph.proc.poll() is not None:
                running = ", ".join(self.graph.pids())
                raise RuntimeError(
                    f"the agent graph gave no output within {REPLY_TIMEOUT_S:g} s "
                    f"(running: {running}; log: {self.graph.log_tail()})"
                )
            self.send()
            if self.outputs(0.2):
                break
        # The other scans' outputs, through kernels still loading (a stage may stall a
        # second on a loaded machine).
        while self.outputs(2.0):
            pass

    def closed_loop(self, count: int, window: int) -> Throughput:
        """``count`` scans with at most ``window`` outstanding; CPU of every party meanwhile."""
        pids = {n: p for n, p in self.graph.pids().items() if n != "launcher"}
        pids_launcher = self.graph.proc.pid
        cpu_before = {n: process_cpu_s(p) for n, p in pids.items()}
        launcher_before = process_cpu_s(pids_launcher)
        bench_before = time.process_time()
        sent = received = 0
        started = time.perf_counter()
        deadline = time.monotonic() + REPLY_TIMEOUT_S
        cpu_at_output, cpu_read = dict(cpu_before), time.monotonic()
        while received < count:
            while sent < count and sent - received < window:
                self.send()
                sent += 1
            got = self.outputs(0.05)
            if got:
                received += got
                deadline = time.monotonic() + REPLY_TIMEOUT_S
                if time.monotonic() - cpu_read > 1.0:  # read a second apart, not per scan
                    cpu_at_output, cpu_read = _cpu_s(pids), time.monotonic()
            elif time.monotonic() > deadline:
                # Which processes worked meanwhile: a busy one is stuck in its work, idle
                # ones wait for messages that were lost; a gone one was replaced.
                now = _cpu_s(pids)
                busy = ", ".join(
                    f"{n} {now[n] - cpu_at_output[n]:.1f}" if now[n] >= 0.0 else f"{n} gone"
                    for n in pids
                )
                raise RuntimeError(
                    f"the agent graph returned {received} of {sent} scans; CPU s since its "
                    f"last output: {busy} (log: {self.graph.log_tail()})"
                )
        elapsed = time.perf_counter() - started
        cpu = {n: process_cpu_s(p) - cpu_before[n] for n, p in pids.items()}
        cpu["bench"] = time.process_time() - bench_before
        cpu["launcher"] = process_cpu_s(pids_launcher) - launcher_before
        return Throughput(received, elapsed, cpu)

    def at_rate(self, count: int) -> dict[str, list[float]]:
        """``count`` scans one per sweep period; each one's latency in s to its features and
        to its environment vector, as they arrived."""
        sent_at: dict[int, float] = {}  # by sweep index
        sweep_of: dict[int, int] = {}  # the features' stamp (the vector's too): its sweep
        latencies: dict[str, list[float]] = {OUTPUT: [], topics.FEATURES: []}

        def collect(timeout_s: float) -> None:
            for received_at, topic, msg in self.receive(timeout_s):
                if isinstance(msg, Features):
                    sweep_of[msg.header.stamp_ns] = msg.sweep_index
                    started = sent_at.get(msg.sweep_index)
                else:
                    sweep = sweep_of.pop(msg.header.stamp_ns, -1)
                    started = sent_at.pop(sweep, None)
                if started is not None:
                    latencies[topic].append(received_at - started)

        next_send = time.perf_counter()
        for _ in range(count):
            while (wait := next_send - time.perf_counter()) > 0:
                collect(wait)
            sent_at[self.seq] = time.perf_counter()
            self.send(time.time())
            next_send += self.period_s
        late = time.perf_counter() + LATE_S
        while sent_at and (wait := late - time.perf_counter()) > 0:
            collect(wait)
        return latencies


def _cpu_s(pids: dict[str, int]) -> dict[str, float]:
    """Each process's CPU seconds so far (:func:`process_cpu_s`); -1 for one that is gone."""
    cpu = {}
    for name, pid in pids.items():
        try:
            cpu[name] = process_cpu_s(pid)
        except OSError:
            cpu[name] = -1.0
    return cpu


def _bench_launch_file(directory: Path) -> Path:
    """``launch/agent.toml`` for the bench: every queued input kept (``backlog = "all"``) and
    the vehicle's states sent from the head's endpoint, so that the bench plays both."""
    path = launch_variant(ROOT / "launch" / "agent.toml", directory, backlog='"all"')
    text = path.read_text()
    vehicle = re.search(r'(?ms)^\[\[external\]\]\nname = "vehicle"\n.*?(?=^\[|\Z)', text)
    head = 'outputs = ["raw_scan", "head_state"]'
    if vehicle is None or head not in text:
        raise RuntimeError(
            "launch/agent.toml changed shape: the bench cannot play head and vehicle"
        )
    text = text.replace(vehicle.group(0), "").replace(
        head, 'outputs = ["raw_scan", "head_state", "vehicle_state"]'
    )
    path.write_text(text)
    load_launch(path)
    return path


def multi_process_figures(scans: list[RawScan], count: int, latency_scans: int) -> dict[str, Any]:
    """Saturated scans per second, CPU per scan and latency at 10 Hz, as processes."""
    with (
        tempfile.TemporaryDirectory(prefix="lepp") as tmp,
        GraphUnderTest(
            _bench_launch_file(Path(tmp)), play="head", listen=(topics.FEATURES,)
        ) as graph,
    ):
        graph.wait_subscribed(topics.RAW_SCAN)
        graph.wait_subscribed(topics.VEHICLE_STATE)
        driver = _Driver(graph, scans)
        driver.first_output()
        driver.closed_loop(WARM_UP_SCANS, IN_FLIGHT)
        run = driver.closed_loop(count, IN_FLIGHT)
        latencies = driver.at_rate(latency_scans)
    work = sum(s for n, s in run.cpu_s.items() if n != "launcher")
    return {
        "scans_per_s": run.scans_per_s,
        "cpu_ms_per_scan": 1e3 * work / run.scans,
        "launcher_cpu_ms_per_scan": 1e3 * run.cpu_s["launcher"] / run.scans,
        "cpu_ms_per_scan_by_process": {n: 1e3 * s / run.scans for n, s in run.cpu_s.items()},
        "latency_ms": percentiles_ms(latencies[topics.FEATURES], latency_scans),
        "latency_ms_to_environment": percentiles_ms(latencies[OUTPUT], latency_scans),
    }
