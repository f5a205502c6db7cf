"""CPU use of each process of the simulated graph (``launch/sim.toml``) at its 10 Hz.

Each figure is the CPU time a process used over the window (its CPU-time clock, to the
nanosecond, all threads: :func:`cli.bench_graph.process_cpu_s`) divided by the window's
wall time, in percent of one core. The window opens once the graph is in its steady state
(environment vectors flowing, then ``SETTLE_S`` more for the scans queued at start) and the
bench has stopped listening. A thread of the bench plays the vehicle controller throughout
(:class:`cli.bench_graph.OdometryRelay`: each ``odometry`` back as the ``vehicle_state``; its
CPU is not counted), so that tracking and the planner work as they would beside a vehicle.

``total`` is the sum over the graph's processes; the launcher (which supervises and, for
its status line, receives every topic) is reported apart, and ``total_with_launcher`` adds
it.
"""

from __future__ import annotations

import time

from agent.runtime import topics
from cli.bench_graph import ROOT, GraphUnderTest, OdometryRelay, process_cpu_s

SETTLE_S = 2.0
START_TIMEOUT_S = 30.0


def cpu_figures(seconds: float) -> dict[str, float]:
    """Percent of one core per process of ``launch/sim.toml`` over ``seconds`` at 10 Hz."""
    if seconds <= 0:
        raise ValueError(f"the window must be positive, got {seconds} s")
    with (
        GraphUnderTest(ROOT / "launch" / "sim.toml", play=None) as graph,
        OdometryRelay(graph),
    ):
        bus = graph.listen()
        deadline = time.monotonic() + START_TIMEOUT_S
        while not any(topic == topics.ENVIRONMENT for topic, _ in bus.poll(0.1)):
            if time.monotonic() > deadline or graph.proc.poll() is not None:
                raise RuntimeError(f"the sim graph gave no environment: {graph.log_tail()}")
        graph.close_bus()
        time.sleep(SETTLE_S)
        pids = graph.pids()
        before = {n: process_cpu_s(p) for n, p in pids.items()}
        started = time.monotonic()
        time.sleep(seconds)
        try:
            after = {n: process_cpu_s(p) for n, p in pids.items()}
        except OSError:
            after = {}
        elapsed = time.monotonic() - started
        if not after or graph.proc.poll() is not None or graph.pids() != pids:
            raise RuntimeError("a process of the sim graph exited or restarted meanwhile")
    share = {n: 100 * (after[n] - before[n]) / elapsed for n in pids}
    graph_total = sum(v for n, v in share.items() if n != "launcher")
    return {**share, "total": graph_total, "total_with_launcher": graph_total + share["launcher"]}
