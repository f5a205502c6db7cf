"""``sensor-agent bench``: how fast the simulation and the agent's stages run. Prints figures.

* ``simulator``: full 256-sample sweeps of the simulated head over a random 50-obstacle world.
* ``pipeline``: the agent's stages of ``launch/agent.toml`` fed pre-simulated raw scans as
  fast as they take them, in one process (the lock-step runner, every message through its
  wire encoding) and as separate processes (the real launcher, real sockets; the bench plays
  the head). Throughput is closed-loop: at most ``IN_FLIGHT`` scans are outstanding, so the
  figure is what the graph sustains without dropping.
* ``latency_ms``: from a raw scan's last sample to the last stage's output, at the real
  10 Hz rate, through the process graph.
* ``cpu_percent``: per process of ``launch/sim.toml`` running at 10 Hz, from /proc.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from agent.calibration.table import load_default_calibration
from agent.kinematics.trajectory import StaticPose
from agent.runtime import topics
from agent.runtime.bus import Bus
from agent.runtime.launch import GraphSpec, load_launch
from agent.runtime.messages import Header, RawScan, decode, stamp_ns
from agent.sensor.params import simulated_head
from agent.sim.simulator import SensorSimulator
from agent.sim.world import load_world
from agent.sim.worldgen import random_world
from cli.output import write_json
from processes.launcher import process_ids
from processes.runtime import lockstep_graph

ROOT = Path(__file__).resolve().parents[1]
IN_FLIGHT = 200
Progress = Callable[[str], None]


def simulator_figures(scans: int, obstacles: int, seed: int) -> dict[str, Any]:
    head = simulated_head()
    rng = np.random.default_rng(seed)
    world = random_world(rng, obstacles)
    sim = SensorSimulator(world, head, rng)
    pose = StaticPose(*world.vehicle_pose)
    sim.sweep(trajectory=pose)  # warm caches
    raws = []
    started = time.perf_counter()
    for i in range(scans):
        raw, _ = sim.sweep(
            trajectory=pose,
            direction=1 if i % 2 == 0 else -1,
            pan_rad=float(rng.uniform(-1.5, 1.5)),
        )
        raws.append(raw)
    sim_s = time.perf_counter() - started
    calibration = load_default_calibration()
    started = time.perf_counter()
    for raw in raws:
        calibration.calibrate_scan(raw)
    cal_s = time.perf_counter() - started
    return {
        "world_obstacles": world.n_obstacles,
        "world_segments": int(world.segments_start.shape[0]),
        "world_circles": int(world.circles_center.shape[0]),
        "scans": scans,
        "scans_per_s": scans / sim_s,
        "ms_per_scan": 1e3 * sim_s / scans,
        "real_time_factor": scans / sim_s * head.sweep_period_s,
        "calibration_us_per_scan": 1e6 * cal_s / scans,
    }


def raw_scans(n: int, seed: int = 0) -> list[RawScan]:
    """Distinct simulated raw scans of the office world (cycled by the bench)."""
    world = load_world(ROOT / "worlds" / "office.toml")
    sim = SensorSimulator(world, simulated_head(), np.random.default_rng(seed))
    pose = StaticPose(*world.vehicle_pose)
    out = []
    for i in range(n):
        raw, _ = sim.sweep(direction=1 if i % 2 == 0 else -1, trajectory=pose, start_time_s=0.1 * i)
        out.append(
            RawScan(
                header=Header(stamp_ns=stamp_ns(float(raw.time_s[-1]))),
                time_s=raw.time_s,
                mirror_angle_rad=raw.mirror_angle_rad,
                pan_rad=raw.pan_rad,
                current_1_A=raw.current_1_A,
                current_2_A=raw.current_2_A,
                direction=raw.direction,
                sweep_index=i,
            )
        )
    return out


def final_topics(graph: GraphSpec) -> list[str]:
    """Topics of the graph that no process of it reads: the last stages' outputs."""
    produced = [t for p in graph.processes for t in p.outputs]
    read = {t for p in graph.processes for t in p.inputs}
    return [t for t in produced if t not in read]


def in_process_rate(graph: GraphSpec, scans: list[RawScan], count: int) -> float:
    runner = lockstep_graph(graph)
    outputs = 0
    last = final_topics(graph)

    def seen(_t: float, topic: str, _msg: object) -> None:
        nonlocal outputs
        outputs += topic in last

    runner.observe(seen)
    started = time.perf_counter()
    for i in range(count):
        runner.inject(topics.RAW_SCAN, scans[i % len(scans)].with_header(seq=i), source="head")
    elapsed = time.perf_counter() - started
    if outputs < count:
        raise RuntimeError(f"in-process pipeline produced {outputs} of {count} outputs")
    return count / elapsed


class GraphUnderTest:
    """``sensor-agent launch FILE`` in a subprocess, with the bench playing an external."""

    def __init__(self, launch_file: Path, play: str | None) -> None:
        self.dir = Path(tempfile.mkdtemp(prefix="lepb"))
        self.runtime = self.dir / "rt"
        self.spec = load_launch(launch_file)
        self.proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "cli.main",
                "launch",
                str(launch_file),
                "--runtime-dir",
                str(self.runtime),
            ],
            cwd=ROOT,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )
        deadline = time.monotonic() + 20
        while not (self.runtime / "graph.json").exists():
            if time.monotonic() > deadline or self.proc.poll() is not None:
                self.stop()
                raise RuntimeError(f"graph {launch_file} did not start")
            time.sleep(0.02)
        self.graph = GraphSpec.from_json((self.runtime / "graph.json").read_text())
        endpoint = None
        if play is not None:
            endpoint = next(e.endpoint for e in self.graph.externals if e.name == play)
        self.bus = Bus(endpoint)
        publishers = self.graph.publishers()
        for topic in final_topics(self.graph):
            self.bus.subscriber.connect(publishers[topic][1])
            self.bus.subscriber.subscribe(topic)

    def wait_subscribed(self, topic: str, timeout_s: float = 20.0) -> None:
        wanted = len(self.graph.subscribers(topic))
        deadline = time.monotonic() + timeout_s
        publisher = self.bus.publisher
        while publisher is not None and publisher.subscriber_count(topic) < wanted:
            if time.monotonic() > deadline:
                raise RuntimeError(f"nobody subscribed to {topic} within {timeout_s} s")
            self.bus.poll(0.02)
        time.sleep(0.3)  # let the final stage's subscription reach this bench too

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if hasattr(self, "bus"):
            self.bus.close()


def multi_process_figures(scans: list[RawScan], count: int, latency_scans: int) -> dict[str, Any]:
    graph = GraphUnderTest(ROOT / "launch" / "agent.toml", play="head")
    try:
        graph.wait_subscribed(topics.RAW_SCAN)
        payloads = [s.with_header(seq=i, source="head").to_wire() for i, s in enumerate(scans)]
        # Throughput, closed loop.
        sent = received = 0
        started = time.perf_counter()
        deadline = started + 60
        while received < count and time.perf_counter() < deadline:
            while sent < count and sent - received < IN_FLIGHT:
                graph.bus.publish(topics.RAW_SCAN, payloads[sent % len(payloads)])
                sent += 1
            received += len(graph.bus.poll(0.001))
        throughput = received / (time.perf_counter() - started)
        # Latency at 10 Hz: each scan's last sample is "now" when it is published.
        for _ in range(3):
            graph.bus.poll(0.05)  # drain
        latencies = []
        period = simulated_head().sweep_period_s
        next_send = time.time()
        for i in range(latency_scans):
            while time.time() < next_send:
                graph.bus.poll(max(0.0, next_send - time.time()))
            base = scans[i % len(scans)]
            now = time.time()
            shifted = base.time_s - base.time_s[-1] + now
            msg = RawScan(
                header=Header(stamp_ns=stamp_ns(now), seq=count + i, source="head"),
                time_s=shifted,
                mirror_angle_rad=base.mirror_angle_rad,
                pan_rad=base.pan_rad,
                current_1_A=base.current_1_A,
                current_2_A=base.current_2_A,
                direction=base.direction,
                sweep_index=count + i,
            )
            graph.bus.publish(topics.RAW_SCAN, msg.to_wire())
            got = False
            wait_until = now + 0.09
            while not got and time.time() < wait_until:
                for _, payload in graph.bus.poll(0.005):
                    out = decode(payload)
                    if getattr(out, "sweep_index", -1) == count + i:
                        latencies.append(1e3 * (time.time() - shifted[-1]))
                        got = True
            next_send = now + period
        lat = np.array(latencies)
        return {
            "multi_process_scans_per_s": throughput,
            "multi_process_scans": received,
            "latency_ms": {
                "p50": float(np.percentile(lat, 50)) if lat.size else None,
                "p99": float(np.percentile(lat, 99)) if lat.size else None,
                "max": float(lat.max()) if lat.size else None,
                "scans": int(lat.size),
                "of": latency_scans,
            },
        }
    finally:
        graph.stop()


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _name_of(pid: int) -> str:
    args = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    return args[args.index(b"--name") + 1].decode() if b"--name" in args else "launcher"


def cpu_figures(seconds: float) -> dict[str, float]:
    graph = GraphUnderTest(ROOT / "launch" / "sim.toml", play=None)
    try:
        # Start-up (imports, joining) is not the steady state: wait for the last stage's
        # output to flow, then a little longer.
        deadline = time.monotonic() + 30
        while not graph.bus.poll(0.1):
            if time.monotonic() > deadline:
                raise RuntimeError("the sim graph produced nothing within 30 s")
        time.sleep(1.0)
        pids = {_name_of(p): p for p in process_ids(graph.runtime)}
        pids["launcher"] = graph.proc.pid
        before = {n: _cpu_seconds(p) for n, p in pids.items()}
        t0 = time.monotonic()
        time.sleep(seconds)
        elapsed = time.monotonic() - t0
        return {n: 100 * (_cpu_seconds(p) - before[n]) / elapsed for n, p in pids.items()}
    finally:
        graph.stop()


def run_bench(
    scans: int,
    obstacles: int,
    seed: int,
    pipeline_scans: int,
    latency_scans: int,
    cpu_seconds: float,
    progress: Progress,
) -> dict[str, Any]:
    progress("simulator")
    sim = simulator_figures(scans, obstacles, seed)
    progress("in-process pipeline")
    agent_graph = load_launch(ROOT / "launch" / "agent.toml")
    raws = raw_scans(50, seed)
    in_rate = in_process_rate(agent_graph, raws, pipeline_scans)
    progress("multi-process pipeline and latency")
    multi = multi_process_figures(raws, pipeline_scans, latency_scans)
    progress("cpu at 10 Hz")
    cpu = cpu_figures(cpu_seconds)
    return {
        "simulator_scans_per_s": sim["scans_per_s"],
        "simulator": sim,
        "pipeline": {
            "stages": [p.name for p in agent_graph.processes],
            "final_topics": final_topics(agent_graph),
            "in_process_scans_per_s": in_rate,
            "multi_process_scans_per_s": multi["multi_process_scans_per_s"],
            "multi_to_in_process": multi["multi_process_scans_per_s"] / in_rate,
        },
        "latency_ms": multi["latency_ms"],
        "cpu_percent": cpu,
    }


def bench_command(args: argparse.Namespace) -> int:
    """``sensor-agent bench``: run the measurements, print them, write JSON."""

    def progress(stage: str) -> None:
        print(f"  measuring {stage} ...", file=sys.stderr, flush=True)

    figures = run_bench(
        args.scans,
        args.obstacles,
        args.seed,
        args.pipeline_scans,
        args.latency_scans,
        args.cpu_seconds,
        progress,
    )
    sim, pipe, lat = figures["simulator"], figures["pipeline"], figures["latency_ms"]
    print(
        f"simulator: {sim['scans_per_s']:.0f} scans/s ({sim['ms_per_scan']:.2f} ms/scan, "
        f"{sim['real_time_factor']:.0f}x real time) over {sim['world_obstacles']} obstacles "
        f"({sim['world_segments']} segments, {sim['world_circles']} circles)"
    )
    print(f"pipeline {' -> '.join(pipe['stages'])} (to {', '.join(pipe['final_topics'])}):")
    print(f"  in one process       {pipe['in_process_scans_per_s']:8.0f} scans/s")
    print(
        f"  as processes         {pipe['multi_process_scans_per_s']:8.0f} scans/s "
        f"({100 * pipe['multi_to_in_process']:.0f} % of in-process)"
    )
    print(
        f"latency at 10 Hz, last sample to last output: p50 {lat['p50']:.2f} ms, "
        f"p99 {lat['p99']:.2f} ms, max {lat['max']:.2f} ms ({lat['scans']} of {lat['of']})"
    )
    print(
        "cpu at 10 Hz (launch/sim.toml): "
        + ", ".join(f"{name} {pct:.2f} %" for name, pct in figures["cpu_percent"].items())
    )
    if args.json is not None:
        write_json(Path(args.json), figures)
    return 0


# ------------------------------------------------------------------------------- perception
FIXED_NOISE_M = 0.01  # the baseline's one σ for every point, as line extractors assume


def perception_figures(scenes: int, seed: int, moving_every: int = 3) -> dict[str, Any]:
    """Filtering and features over random scenes, scored against the truth (see bench doc).

    The scans go through the filtering and features stages themselves; the baseline is the
    same features stage fed the same points with one fixed noise for all of them.
    """
    from dataclasses import replace

    from agent.calibration.characterisation import head_centred_pose
    from agent.kinematics.trajectory import ConstantTwist, Trajectory
    from agent.perception import kernels
    from agent.perception.evaluation import Tally, paired_accuracy, score_scan
    from agent.perception.filtering import PoseHistory
    from agent.sim.worldgen import perception_scene
    from agent.stages.calibration_stage import CalibrationStage
    from agent.stages.features_stage import FeaturesStage
    from agent.stages.filtering_stage import FilteringStage

    head = simulated_head()
    calibration = load_default_calibration()
    calibrate = CalibrationStage(calibration)
    filtering = FilteringStage(calibration.noise_current_A, mount_offset_m=head.mount_offset_m)
    features = FeaturesStage(calibration.signal_constant_Am2, calibration.noise_current_A)
    # The baseline knows no per-sample noise: one fixed σ for every point, no intensities.
    plain_features = FeaturesStage(calibration.signal_constant_Am2)
    kernels.warm_up()  # load the compiled loops first: a one-off cost, not a scan's
    rng = np.random.default_rng(seed)
    weighted, baseline = Tally(), Tally()
    elapsed = 0.0
    for i in range(scenes):
        world = perception_scene(rng)
        trajectory: Trajectory = head_centred_pose(head)
        if i % moving_every == moving_every - 1:  # some scans while driving and turning
            trajectory = ConstantTwist(
                -head.mount_offset_m,
                0.0,
                0.0,
                float(rng.uniform(0.2, 0.5)),
                float(rng.uniform(-1, 1)),
            )
        sim = SensorSimulator(world, head, rng)
        raw, truth = sim.sweep(direction=1 if i % 2 else -1, trajectory=trajectory)
        scan = calibrate.calibrated_message(raw, stamp_ns(float(raw.time_s[-1])), i)
        filtering.poses = PoseHistory.sampled(
            trajectory, scan.time_s[0] - 0.05, scan.time_s[-1] + 0.02
        )
        started = time.perf_counter()
        filtered = filtering.filter(scan)
        found = features.extract(filtered)
        elapsed += time.perf_counter() - started
        fixed = np.broadcast_to(np.eye(2) * FIXED_NOISE_M**2, filtered.covariance.shape).copy()
        plain = plain_features.extract(replace(filtered, covariance=fixed))
        x, y, yaw = (float(v[0]) for v in trajectory.poses_at(np.array([scan.time_s[-1]])))
        for tally, found_here in ((weighted, found), (baseline, plain)):
            score_scan(
                tally,
                world,
                truth,
                scan.range_m,
                scan.sigma_m,
                filtered.flag,
                found_here,
                (x, y, yaw),
            )
    figures = weighted.summary()
    figures["per_scan_ms"] = 1e3 * elapsed / scenes
    figures["paired_with_baseline"] = paired_accuracy(weighted, baseline)
    figures["seed"] = seed
    figures["baseline"] = baseline.summary()
    figures["baseline"]["description"] = (
        f"the same filter and extractor with equal weights, a fixed {FIXED_NOISE_M} m noise "
        "and no intensities in the fits"
    )
    return figures


def perception_command(args: argparse.Namespace) -> int:
    """``sensor-agent bench perception``."""
    f = perception_figures(args.scenes, args.seed)
    b = f["baseline"]

    def show(value: Any, fmt: str) -> str:
        return "n/a" if value is None else format(value, fmt)

    print(
        f"perception over {f['scans']} scenes ({f['true_segments']} true segments, "
        f"{f['true_cylinders']} true cylinders), seed {args.seed}"
    )
    rows = [
        ("phantom rate", "phantom_rate", ".3%"),
        ("valid loss", "valid_loss_rate", ".3%"),
        ("segments detected", "segment_detection_rate", ".1%"),
        ("cylinders detected", "cylinder_detection_rate", ".1%"),
        ("false features per scan", "false_features_per_scan", ".3f"),
        ("segment NEES mean (2 dof)", "segment_nees_mean", ".2f"),
        ("cylinder NEES mean (3 dof)", "cylinder_nees_mean", ".2f"),
        ("segment rho RMS error (m)", "segment_rho_rms_m", ".4f"),
        ("reflectivity error (median)", "reflectivity_rel_err_median", ".1%"),
    ]
    print(f"  {'':30s} {'weighted':>10s} {'baseline':>10s}")
    for label, key, fmt in rows:
        print(f"  {label:30s} {show(f[key], fmt):>10s} {show(b[key], fmt):>10s}")
    print(
        f"  false features by kind: {f['false_features_by_kind']} "
        f"(baseline {b['false_features_by_kind']})"
    )
    pair = f["paired_with_baseline"]

    def pair_row(label: str, key: str, scale: float, unit: str) -> None:
        if pair[f"{key}_a_better"] is None:
            return
        for stat in ("rms", "median_abs"):
            got = pair[f"{key}_{stat}"]
            text = [f"{v * scale:.2f} {unit}" for v in got]
            print(f"    {label + ' ' + stat.replace('_abs', ''):28s} {text[0]:>10s} {text[1]:>10s}")
        print(f"    {label + ' weighted better':28s} {pair[f'{key}_a_better']:>10.0%}")

    print(
        f"  on the surfaces both found ({pair['segments']} segments, "
        f"{pair['cylinders']} cylinders):"
    )
    pair_row("segment alpha", "segment_alpha", 1e3, "mrad")
    pair_row("segment rho", "segment_rho", 1e3, "mm")
    pair_row("cylinder centre", "cylinder_center", 1e3, "mm")
    pair_row("cylinder radius", "cylinder_radius", 1e3, "mm")
    print(f"  filtering + features: {f['per_scan_ms']:.3f} ms per scan (one process)")
    if args.json is not None:
        write_json(Path(args.json), f)
    return 0
