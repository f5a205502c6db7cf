"""``sensor-agent bench``: how fast the simulation, the codec, the bus and the agent's stages
run. Prints figures, one block per section, and writes them all with ``--json``.

* ``simulator``: full 256-sample sweeps of the simulated head over a random 50-obstacle world.
* ``codec_us``: per message type, the median µs of ``to_wire`` and of ``decode`` with full
  validation, in one process, over realistic messages (:mod:`cli.bench_codec`);
  ``message_bytes`` their encoded size.
* ``hop_us``: per message type, p50 and p99 µs of one hop between two OS processes (encode,
  publish, ipc socket, poll, receive, decode), from a ping-pong; ``transport`` the bare
  sockets for the largest message's bytes (:mod:`cli.bench_hop`).
* ``pipeline``: the agent's stages of ``launch/agent.toml`` saturated, in one process and as
  processes, doing the same work per scan, with the CPU each takes per scan
  (:mod:`cli.bench_pipeline`).
* ``pipeline``'s stages run from calibration to the planner, the bench sending a vehicle state
  (standing) before each scan; a scan is through when its environment vector is out.
* ``latency_ms``: from a raw scan's last sample to its features received and decoded, at the
  real 10 Hz rate, through the process graph; ``latency_ms_in_process`` the same in one
  process; ``latency_ms_to_environment`` (``..._in_process``) the same to its environment
  vector, through tracking and the planner.
* ``cpu_percent``: per process of ``launch/sim.toml`` running at 10 Hz, in percent of one
  core, with the graph's ``total`` (:mod:`cli.bench_cpu`).
"""

from __future__ import annotations

import argparse
import gc
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from agent.calibration.table import load_default_calibration
from agent.kinematics.trajectory import StaticPose
from agent.runtime.launch import load_launch
from agent.sensor.params import simulated_head
from agent.sim.simulator import SensorSimulator
from agent.sim.worldgen import random_world
from cli.bench_codec import codec_figures, message_bytes
from cli.bench_cpu import cpu_figures
from cli.bench_graph import final_topics
from cli.bench_hop import hop_figures
from cli.bench_messages import AGENT_LAUNCH, graph_messages, raw_scans
from cli.bench_pipeline import IN_FLIGHT, WARM_UP_SCANS, in_process_figures, multi_process_figures
from cli.output import write_json

RAW_SCANS = 50  # distinct raw scans the pipeline cycles through
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


def run_bench(
    *,
    scans: int,
    obstacles: int,
    seed: int,
    pipeline_scans: int,
    latency_scans: int,
    cpu_seconds: float,
    codec_calls: int,
    hop_round_trips: int,
    hop_warm_up: int,
    progress: Progress,
) -> dict[str, Any]:
    progress("simulator")
    sim = simulator_figures(scans, obstacles, seed)
    progress("messages of the agent graph")
    agent_graph = load_launch(AGENT_LAUNCH)
    raws = raw_scans(RAW_SCANS, seed)
    samples = graph_messages(raws)
    # As every process shell does (processes/runtime.py): what start-up made stays out of the
    # collector's full passes, so the bench's side of each measurement runs as a stage's does.
    gc.freeze()
    progress("codec")
    codec = codec_figures(samples, codec_calls)
    progress("hop between two processes")
    hop = hop_figures(samples, hop_round_trips, hop_warm_up)
    progress("pipeline in one process")
    one = in_process_figures(agent_graph, raws, pipeline_scans, latency_scans)
    progress("pipeline as processes")
    multi = multi_process_figures(raws, pipeline_scans, latency_scans)
    progress(f"cpu at 10 Hz ({cpu_seconds:g} s)")
    cpu = cpu_figures(cpu_seconds)
    return {
        "simulator_scans_per_s": sim["scans_per_s"],
        "simulator": sim,
        "codec_us": codec,
        "message_bytes": message_bytes(samples),
        "hop_us": hop,
        "pipeline": {
            "stages": [p.name for p in agent_graph.processes],
            "final_topics": final_topics(agent_graph),
            "in_process_scans_per_s": one["scans_per_s"],
            "multi_process_scans_per_s": multi["scans_per_s"],
            "multi_to_in_process": multi["scans_per_s"] / one["scans_per_s"],
            "in_process_cpu_ms_per_scan": one["cpu_ms_per_scan"],
            "multi_process_cpu_ms_per_scan": multi["cpu_ms_per_scan"],
            "multi_process_cpu_ms_per_scan_by_process": multi["cpu_ms_per_scan_by_process"],
            "launcher_cpu_ms_per_scan": multi["launcher_cpu_ms_per_scan"],
            "scans": pipeline_scans,
            "warm_up_scans": WARM_UP_SCANS,
            "in_flight": IN_FLIGHT,
        },
        "latency_ms": multi["latency_ms"],
        "latency_ms_in_process": one["latency_ms"],
        "latency_ms_to_environment": multi["latency_ms_to_environment"],
        "latency_ms_to_environment_in_process": one["latency_ms_to_environment"],
        "cpu_percent": cpu,
        "cpu_window_s": cpu_seconds,
        "settings": {
            "codec_calls": codec_calls,
            "hop_round_trips": hop_round_trips,
            "hop_warm_up": hop_warm_up,
            "raw_scans": RAW_SCANS,
            "seed": seed,
        },
    }


def print_figures(figures: dict[str, Any]) -> None:
    """The figures as the command prints them: one block per section."""
    sim, pipe = figures["simulator"], figures["pipeline"]
    print(
        f"simulator: {sim['scans_per_s']:.0f} scans/s ({sim['ms_per_scan']:.2f} ms/scan, "
        f"{sim['real_time_factor']:.0f}x real time) over {sim['world_obstacles']} obstacles "
        f"({sim['world_segments']} segments, {sim['world_circles']} circles)"
    )
    settings = figures["settings"]
    print(f"\ncodec, one process (median µs per call over {settings['codec_calls']} calls):")
    print(f"  {'message':16s} {'bytes':>7s} {'encode':>8s} {'decode':>8s}")
    for topic, us in figures["codec_us"].items():
        size = figures["message_bytes"][topic]
        print(f"  {topic:16s} {size:7d} {us['encode']:8.1f} {us['decode']:8.1f}")
    hops = figures["hop_us"]
    print(
        f"\nhop between two processes (µs: encode, publish, ipc, poll, receive, decode; "
        f"half of {settings['hop_round_trips']} round trips each):"
    )
    print(f"  {'message':16s} {'p50':>8s} {'p99':>8s}")
    for topic, us in hops.items():
        if topic != "transport":
            print(f"  {topic:16s} {us['p50']:8.1f} {us['p99']:8.1f}")
    t = hops["transport"]
    print(
        f"  {'transport':16s} {t['p50']:8.1f} {t['p99']:8.1f}  "
        f"(the {t['bytes']} bytes of a {t['message']}, not decoded)"
    )
    by_process = ", ".join(
        f"{n} {ms:.2f}" for n, ms in pipe["multi_process_cpu_ms_per_scan_by_process"].items()
    )
    print(
        f"\npipeline {' -> '.join(pipe['stages'])} (to {', '.join(pipe['final_topics'])}), "
        f"saturated, {pipe['scans']} scans:"
    )
    print(
        f"  in one process  {pipe['in_process_scans_per_s']:7.0f} scans/s   "
        f"{pipe['in_process_cpu_ms_per_scan']:.2f} ms CPU per scan"
    )
    print(
        f"  as processes    {pipe['multi_process_scans_per_s']:7.0f} scans/s   "
        f"{pipe['multi_process_cpu_ms_per_scan']:.2f} ms CPU per scan "
        f"({100 * pipe['multi_to_in_process']:.0f} % of in-process throughput; "
        f"ms per scan: {by_process})"
    )
    print("\nlatency at 10 Hz, last sample of a raw scan to its features / environment decoded:")
    for label, key in (
        ("in one process", "latency_ms_in_process"),
        ("as processes", "latency_ms"),
        ("in one process", "latency_ms_to_environment_in_process"),
        ("as processes", "latency_ms_to_environment"),
    ):
        lat = figures[key]
        label = f"{label}, {'environment' if 'environment' in key else 'features'}"
        if lat["scans"] == 0:
            print(f"  {label:27s}  no output (of {lat['of']} scans)")
            continue
        print(
            f"  {label:27s}  p50 {lat['p50']:6.2f} ms   p99 {lat['p99']:6.2f} ms   "
            f"max {lat['max']:6.2f} ms   ({lat['scans']} of {lat['of']} scans)"
        )
    cpu = figures["cpu_percent"]
    print(f"\ncpu at 10 Hz (launch/sim.toml, % of one core over {figures['cpu_window_s']:g} s):")
    names = [n for n in cpu if n not in ("launcher", "total", "total_with_launcher")]
    print("  " + ", ".join(f"{n} {cpu[n]:.2f}" for n in names))
    print(
        f"  graph total {cpu['total']:.2f} %; launcher {cpu['launcher']:.2f} %; "
        f"with the launcher {cpu['total_with_launcher']:.2f} %"
    )


def bench_command(args: argparse.Namespace) -> int:
    """``sensor-agent bench``: run the measurements, print them, write JSON."""
    for name, least in (
        ("pipeline_scans", 1),
        ("latency_scans", 1),
        ("cpu_seconds", 0.1),
        ("codec_calls", 1),
        ("hop_round_trips", 1),
        ("hop_warm_up", 0),
    ):
        if getattr(args, name) < least:
            flag = "--" + name.replace("_", "-")
            print(f"sensor-agent: {flag} must be at least {least}", file=sys.stderr)
            return 2
    started = time.monotonic()

    def say(text: str) -> None:
        print(f"  [{time.monotonic() - started:5.1f} s] {text}", file=sys.stderr, flush=True)

    def progress(stage: str) -> None:
        say(f"measuring {stage} ...")

    figures = run_bench(
        scans=args.scans,
        obstacles=args.obstacles,
        seed=args.seed,
        pipeline_scans=args.pipeline_scans,
        latency_scans=args.latency_scans,
        cpu_seconds=args.cpu_seconds,
        codec_calls=args.codec_calls,
        hop_round_trips=args.hop_round_trips,
        hop_warm_up=args.hop_warm_up,
        progress=progress,
    )
    say("done")
    print_figures(figures)
    if args.json is not None:
        write_json(Path(args.json), figures)
    return 0


def faults_command(args: argparse.Namespace) -> int:
    """``sensor-agent bench faults``."""
    from cli.bench_faults import fault_figures, print_fault_figures

    figures = fault_figures(args.trials, progress=lambda text: print(f"  {text}", flush=True))
    print_fault_figures(figures)
    if args.json:
        write_json(Path(args.json), figures)
    return 0


def perception_command(args: argparse.Namespace) -> int:
    """``sensor-agent bench perception`` (:mod:`cli.bench_perception`)."""
    from cli.bench_perception import perception_command as run

    return run(args)
