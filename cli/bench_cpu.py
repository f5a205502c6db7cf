"""CPU use of each process of the simulated graph (``launch/sim.toml``) at its 10 Hz.

Each figure is the CPU time a process used over the window (its CPU-time clock, to the
nanosecond, all threads: :func:`cli.bench_graph.process_cpu_s`) divided by the window's
wall time, in percent of one core. The window opens once the graph is in its steady state
(environment vectors flowing, then ``SETTLE_S`` more for the scans queued at start). The
bench plays the vehicle controller meanwhile: it passes each ``odometry`` on as the
``vehicle_state`` (its own CPU is not counted), so that tracking and the planner work as they
would beside a vehicle.

``total`` is the sum over the graph's processes; the launcher (which supervises and, for
its status line, receives every topic) is reported apart, and ``total_with_launcher`` adds
it.
"""

from __future__ import annotations

import time

import numpy as np

from agent.runtime import topics
from agent.runtime.bus import Bus
from agent.runtime.messages import Header, Odometry, VehicleState, decode
from cli.bench_graph import ROOT, GraphUnderTest, process_cpu_s

SETTLE_S = 2.0
START_TIMEOUT_S = 30.0


def vehicle_state_of(odometry: Odometry) -> VehicleState:
    """The vehicle controller's part, played by the bench: its odometry as the agent's
    vehicle state (no intent)."""
    return VehicleState(
        header=Header(stamp_ns=odometry.header.stamp_ns, frame_id="odom"),
        x_m=odometry.x_m, y_m=odometry.y_m, yaw_rad=odometry.yaw_rad,
        speed_m_s=odometry.speed_m_s, yaw_rate_rad_s=odometry.yaw_rate_rad_s,
        pose_covariance=odometry.pose_covariance, intent_xy=np.zeros((0, 2)),
    )  # fmt: skip


def _relay(bus: Bus, timeout_s: float) -> set[str]:
    """Pass the world's odometry on as vehicle states for up to ``timeout_s``; the topics seen."""
    seen = set()
    for topic, payload in bus.poll(timeout_s):
        seen.add(topic)
        if topic == topics.ODOMETRY:
            odometry = decode(payload, expect=Odometry)
            bus.publish(topics.VEHICLE_STATE, vehicle_state_of(odometry).to_wire(source="bench"))
    return seen


def cpu_figures(seconds: float) -> dict[str, float]:
    """Percent of one core per process of ``launch/sim.toml`` over ``seconds`` at 10 Hz."""
    if seconds <= 0:
        raise ValueError(f"the window must be positive, got {seconds} s")
    with GraphUnderTest(
        ROOT / "launch" / "sim.toml", play="controller", listen=(topics.ODOMETRY,)
    ) as graph:
        bus = graph.listen()
        deadline = time.monotonic() + START_TIMEOUT_S
        while topics.ENVIRONMENT not in _relay(bus, 0.1):
            if time.monotonic() > deadline or graph.proc.poll() is not None:
                raise RuntimeError(f"the sim graph gave no environment: {graph.log_tail()}")
        settle = time.monotonic() + SETTLE_S
        while time.monotonic() < settle:
            _relay(bus, 0.1)
        pids = graph.pids()
        before = {n: process_cpu_s(p) for n, p in pids.items()}
        started = time.monotonic()
        while time.monotonic() < started + seconds:
            _relay(bus, max(0.0, min(0.1, started + seconds - time.monotonic())))
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
