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
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agent.runtime import topics
from agent.runtime.launch import GraphSpec
from agent.runtime.messages import Message, RawScan, decode, stamp_ns
from agent.sensor.params import simulated_head
from cli.bench_graph import ROOT, GraphUnderTest, final_topics, launch_variant, process_cpu_s
from processes.runtime import lockstep_graph

IN_FLIGHT = 50  # scans outstanding while saturated: half of HWM, whatever queue they are in
WARM_UP_SCANS = 50
REPLY_TIMEOUT_S = 30.0  # for a scan's output while the graph starts on a shared machine
LATE_S = 2.0  # how long the bench waits for the last outputs at 10 Hz


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
    last = set(final_topics(graph))
    outputs: list[tuple[float, Message]] = []

    def seen(_t: float, topic: str, msg: Message) -> None:
        if topic in last:
            outputs.append((time.perf_counter(), msg))

    runner.observe(seen)
    seq = 0
    for _ in range(WARM_UP_SCANS):
        runner.inject(topics.RAW_SCAN, scans[seq % len(scans)].with_header(seq=seq), source="head")
        seq += 1
    outputs.clear()
    cpu_started = time.process_time()
    started = time.perf_counter()
    for _ in range(count):
        runner.inject(topics.RAW_SCAN, scans[seq % len(scans)].with_header(seq=seq), source="head")
        seq += 1
    elapsed = time.perf_counter() - started
    cpu_s = time.process_time() - cpu_started
    if len(outputs) < count:
        raise RuntimeError(f"in-process pipeline produced {len(outputs)} of {count} outputs")
    # At 10 Hz: one scan every sweep period, caches as cold as they are between scans.
    period = simulated_head().sweep_period_s
    latencies = []
    next_send = time.perf_counter()
    for _ in range(latency_scans):
        time.sleep(max(0.0, next_send - time.perf_counter()))
        outputs.clear()
        sent = time.perf_counter()
        scan = _ending_now(scans[seq % len(scans)], time.time(), seq)
        runner.inject(topics.RAW_SCAN, scan, source="head")
        seq += 1
        if outputs:
            latencies.append(outputs[-1][0] - sent)
        next_send += period
    return {
        "scans_per_s": count / elapsed,
        "cpu_ms_per_scan": 1e3 * cpu_s / count,
        "latency_ms": percentiles_ms(latencies, latency_scans),
    }


# ------------------------------------------------------------------------------- as processes
class _Driver:
    """The bench's side of the agent graph: sends raw scans, receives and decodes outputs."""

    def __init__(self, graph: GraphUnderTest, scans: list[RawScan]) -> None:
        self.graph = graph
        self.bus = graph.listen()
        self.scans = scans
        self.seq = 0
        self.types = {t: topics.message_type(t) for t in final_topics(graph.graph)}

    def send(self) -> None:
        scan = self.scans[self.seq % len(self.scans)]
        self.bus.publish(topics.RAW_SCAN, scan.to_wire(seq=self.seq, source="head"))
        self.seq += 1

    def receive(self, timeout_s: float) -> list[tuple[float, Message]]:
        """Outputs that arrive within ``timeout_s`` (maybe none), with their receipt time."""
        got = []
        for topic, payload in self.bus.poll(timeout_s):
            msg = decode(payload, expect=self.types[topic])
            got.append((time.perf_counter(), msg))
        return got

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
            if self.receive(0.2):
                break
        while self.receive(0.5):  # the other scans' outputs, through kernels still loading
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
        while received < count:
            while sent < count and sent - received < window:
                self.send()
                sent += 1
            got = len(self.receive(0.05))
            if got:
                received += got
                deadline = time.monotonic() + REPLY_TIMEOUT_S
            elif time.monotonic() > deadline:
                raise RuntimeError(f"the agent graph returned {received} of {sent} scans")
        elapsed = time.perf_counter() - started
        cpu = {n: process_cpu_s(p) - cpu_before[n] for n, p in pids.items()}
        cpu["bench"] = time.process_time() - bench_before
        cpu["launcher"] = process_cpu_s(pids_launcher) - launcher_before
        return Throughput(received, elapsed, cpu)

    def at_rate(self, count: int, period_s: float) -> list[float]:
        """``count`` scans one per ``period_s``; each one's latency in s, as it arrived."""
        sent_at: dict[int, float] = {}
        latencies: list[float] = []

        def collect(timeout_s: float) -> None:
            for received_at, msg in self.receive(timeout_s):
                started = sent_at.pop(getattr(msg, "sweep_index", -1), None)
                if started is not None:
                    latencies.append(received_at - started)

        next_send = time.perf_counter()
        for _ in range(count):
            while (wait := next_send - time.perf_counter()) > 0:
                collect(wait)
            sent = time.perf_counter()
            scan = _ending_now(self.scans[self.seq % len(self.scans)], time.time(), self.seq)
            sent_at[self.seq] = sent
            self.bus.publish(topics.RAW_SCAN, scan.to_wire(source="head"))
            self.seq += 1
            next_send += period_s
        late = time.perf_counter() + LATE_S
        while sent_at and (wait := late - time.perf_counter()) > 0:
            collect(wait)
        return latencies


def multi_process_figures(scans: list[RawScan], count: int, latency_scans: int) -> dict[str, Any]:
    """Saturated scans per second, CPU per scan and latency at 10 Hz, as processes."""
    with (
        tempfile.TemporaryDirectory(prefix="lepp") as tmp,
        GraphUnderTest(
            launch_variant(ROOT / "launch" / "agent.toml", Path(tmp), backlog='"all"'), play="head"
        ) as graph,
    ):
        graph.wait_subscribed(topics.RAW_SCAN)
        driver = _Driver(graph, scans)
        driver.first_output()
        driver.closed_loop(WARM_UP_SCANS, IN_FLIGHT)
        run = driver.closed_loop(count, IN_FLIGHT)
        latencies = driver.at_rate(latency_scans, simulated_head().sweep_period_s)
    work = sum(s for n, s in run.cpu_s.items() if n != "launcher")
    return {
        "scans_per_s": run.scans_per_s,
        "cpu_ms_per_scan": 1e3 * work / run.scans,
        "launcher_cpu_ms_per_scan": 1e3 * run.cpu_s["launcher"] / run.scans,
        "cpu_ms_per_scan_by_process": {n: 1e3 * s / run.scans for n, s in run.cpu_s.items()},
        "latency_ms": percentiles_ms(latencies, latency_scans),
    }
