"""``sensor-agent``: the command line of the LEP active-sensing agent.

Subcommands
-----------
characterise  reproduce the chapter's sensor characterisation (section 6.6-6.7) from simulation
calibrate     scan calibration targets, build the range look-up table, report before/after
scan          one sweep of the simulated head over a world file
demo          the closed loop: the vehicle drives a world's task on the environment vector
bench         measure how fast the simulation and the agent's stages run
evaluate      closed-loop runs over many worlds, in parallel: outcome rates, score, plots
launch        start a process graph from a launch file and supervise it
keys          make CURVE keys for tcp:// endpoints
systemd       write systemd units for one host's part of a graph (docs/deploy.md)
warm-up       compile the numerical kernels into their caches (once, at install)
export        a recording with Foxglove's schemas (--foxglove)
view          serve a running graph to the Foxglove app
head-emulator the head's firmware on a pseudo-terminal; safety-test, fuzz, soak: its checks

Bad input (a world or calibration file, an out-of-range head command) prints one line naming
the problem and exits with status 2.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from agent.errors import SensorAgentError
from cli.output import write_json

log = logging.getLogger("sensor-agent")
Command = Callable[[argparse.Namespace], int]


def _lazy(module: str, name: str) -> Command:
    """A command imported only when it runs (the sensor commands need scipy: ~1 s)."""

    def run(args: argparse.Namespace) -> int:
        command: Command = getattr(importlib.import_module(module), name)
        return command(args)

    return run


# ----------------------------------------------------------------------------------- launch
def _print_summary(summary: dict[str, Any]) -> None:
    print(f"graph {summary['graph']} stopped: {summary['stop_reason']}")
    for name, p in summary["processes"].items():
        print(f"  {name:12s} exit {p['exit_code']!s:>4}  restarts {p['restarts']}")
    for topic, t in summary["topics"].items():
        gap = t["max_gap_s"]
        print(
            f"  {topic:16s} {t['count']:7d} msgs  {t['rate_hz']:8.2f} Hz  "
            + (
                f"max gap {gap:.3f} s"
                if gap is not None
                else "max gap     - (measured only with --record)"
            )
        )


def cmd_warm_up(args: argparse.Namespace) -> int:
    import agent.perception
    import agent.planning.free_space as free_space
    import agent.sim.simulator as sim
    import agent.stages.world_stage as world
    import agent.tracking
    from agent.control import controller

    start = time.perf_counter()
    agent.perception.warm_up()
    sim.warm_up()
    agent.tracking.warm_up()
    free_space.warm_up()
    controller.warm_up()
    world.load_kernels()
    print(f"compiled kernels ready in {time.perf_counter() - start:.1f} s")
    return 0


def cmd_launch(args: argparse.Namespace) -> int:
    from agent.runtime.launch import load_launch
    from processes.launcher import Launcher

    graph = load_launch(args.file)
    if args.host is not None and not graph.on_host(args.host):
        hosts = sorted({p.host for p in graph.processes})
        print(
            f"sensor-agent: launch file {args.file}: no process on host {args.host!r} "
            f"(hosts: {', '.join(hosts)})",
            file=sys.stderr,
        )
        return 2
    if args.duration is not None and args.duration <= 0:
        print("sensor-agent: --duration must be positive", file=sys.stderr)
        return 2
    recorder = None
    if args.record is not None:
        from agent.runtime.recording import Recorder

        recorder = Recorder(args.record)
    try:
        launcher = Launcher(graph, host=args.host, runtime_dir=args.runtime_dir, recorder=recorder)
    except BaseException:
        if recorder is not None:
            recorder.close()  # an unclosed MCAP file is unreadable
        raise
    print(
        f"graph {graph.name}: {len(launcher.children)} processes, runtime directory "
        f"{launcher.runtime}",
        flush=True,
    )
    status = launcher.run(args.duration)
    summary = launcher.summary()
    _print_summary(summary)
    if args.record is not None:
        print(f"recorded {args.record}")
    if args.json is not None:
        write_json(Path(args.json), summary)
    return status


def cmd_keys(args: argparse.Namespace) -> int:
    from agent.runtime.bus import create_keys

    directory = create_keys(args.dir, force=args.force)
    print(
        f"wrote CURVE keys to {directory}: server.key(_secret), client.key(_secret), "
        "authorized/ (copy the directory to every host of the graph)"
    )
    return 0


# ------------------------------------------------------------------------------------ parser
def _window_arg(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None


_TRACKING_DESCRIPTION = """\
Random dynamic scenes (walls, boxes, cylinders, 0-3 movers up to 0.8 m/s) while the vehicle
drives a scripted path at 0.4 m/s (its odometry drifting), in lock-step; tracks and the
environment vector's free space scored against the truth. Definitions (agent/scoring):

truth in odom      a true point p is scored at T_odom(t)·T_true(t)^-1·p (both poses at the
                   scan's stamp): where a perfect tracker using this odometry puts it
gospa              GOSPA, c 0.5 m, p 1, alpha 2, per scan, between the point objects
                   (corners, cylinders, movers) that should be known (within 2.5 m of the
                   centre of scanning and hit by the samples of 3 scans or more: ever if
                   static, in the last 1 s if moving) and the confirmed corner and
                   cylinder tracks (same kind only); mean over scans with its
                   localisation/missed/false parts
position_rmse_m    per kind over track-truth pairs nearer than c (a track keeps its object
                   while within c); segments: track midpoint to the face's line
nees               static: x, y of corners and static cylinders (2 dof); moving: movers'
                   x, y, vx, vy (4 dof); segment: alpha, rho (2 dof, kept apart); the mean
                   of each run's mean over the runs, with the chi2 95 % interval
id_switches        a track changing object, or another live id taking an object over
fragmentations     an object tracked under a new id after its track was deleted
static_deleted_out_of_view  confirmed static tracks deleted outside the scan's wedge
false_tracks_per_scan       confirmed tracks with no true object of their kind within c
confirm_latency_s  movers: first scan hitting it to the first with a confirmed track on it
false_free_rate    of the bearings the environment vector claims clear, those claiming
                   > 1 cm beyond the first true surface (movers included, at the stamp)
free_coverage      claimed over truly clear distance, both capped at 2.5 m
per_scan_ms        the tracking stage's handle() per features message: p50, p99; tracks:
                   the mean number of tracks held
baseline           Stone Soup's GNN tracker (2-D assignment, CV Kalman filter, multi-
                   measurement initiator, deleter by steps without update) on the same
                   point detections; skipped when Stone Soup is not installed
"""


_EVALUATE_USAGE = """\
sensor-agent evaluate (--random N [--seed S] | WORLD_OR_DIR ...) --policy P [--jobs J]
                             [--shard K/N] [--json FILE] [--plots DIR] [--cluster ADDRESS]
       sensor-agent evaluate merge A.json B.json ... --json OUT [--plots DIR]
       sensor-agent evaluate plot A.json B.json ... --plots DIR"""

_EVALUATE_DESCRIPTION = """\
Drive each world's task in closed loop (the agent, the vehicle controller on its environment
vector, the simulated world, in lock-step) to its outcome: success, collision (by the vehicle
or by a mover), timeout, stale_stop (held for want of a valid environment vector), or error
(the run raised; the evaluation goes on). Prints outcome rates with 95 % Wilson intervals,
score, clearance, docking error and the realtime factor, over all runs and per task kind.

--random N        run i is world i of agent.sim.taskgen.random_tasks(N, seed)
WORLD_OR_DIR      world files with a [task] table; a directory: its *.toml files, sorted
--shard K/N       only the runs i (from 0) with i % N == K - 1 (K from 1); join the shards'
                  JSON files with `evaluate merge`, which writes what one run would have
merge             shards' JSON files into one (refuses other policies, seeds or run lists,
                  and runs missing or in two shards)
plot              several evaluations side by side: success and mean score by policy, and
                  paired score differences between evaluations of the same seed and worlds
"""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sensor-agent",
        description="Active-sensing agent for a synchronised-scanning LEP laser range sensor.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser(
        "characterise",
        help="reproduce the chapter's sensor characterisation",
        description="Cardboard target on axis at 0.75-2.5 m; least squares on "
        "log plots for S, I_n, T and fd; Table 1; edge accuracy.",
    )
    p.add_argument("--samples", type=int, default=1000, help="readings per range (1000)")
    p.add_argument("--seed", type=int, default=1, help="noise seed (1)")
    p.add_argument("--json", metavar="FILE", help="write the results as JSON")
    p.add_argument("--plots", metavar="DIR", help="write figs. 6.7-6.11 as PNG files here")
    p.add_argument("--calibration", metavar="FILE", help="calibration file (default: shipped)")
    p.set_defaults(func=_lazy("cli.sensor_commands", "characterise_command"))

    p = sub.add_parser(
        "calibrate",
        help="build the range look-up table from target scans",
        description="Scan planar targets at known ranges, build the look-up "
        "table, characterise, and report range error before and "
        "after calibration.",
    )
    p.add_argument(
        "--out",
        metavar="FILE",
        default="calibration.npz",
        help="where to write the calibration (calibration.npz)",
    )
    p.add_argument("--seed", type=int, default=2024, help="noise seed (2024)")
    p.add_argument("--planes", type=int, default=48, help="number of target planes (48)")
    p.add_argument("--sweeps", type=int, default=32, help="sweeps per plane (32)")
    p.add_argument(
        "--eval-sweeps", type=int, default=100, help="sweeps per range when evaluating (100)"
    )
    p.add_argument("--json", metavar="FILE", help="write the report as JSON")
    p.set_defaults(func=_lazy("cli.sensor_commands", "calibrate_command"))

    p = sub.add_parser("scan", help="one sweep of the simulated head over a world file")
    p.add_argument("--world", required=True, metavar="FILE", help="world TOML file")
    p.add_argument(
        "--pose",
        nargs=3,
        type=float,
        metavar=("X", "Y", "YAW_DEG"),
        help="vehicle pose (default: the world file's [vehicle] pose)",
    )
    p.add_argument("--pan", type=float, default=0.0, metavar="DEG", help="head pan (0)")
    p.add_argument(
        "--window",
        nargs=2,
        type=_window_arg,
        metavar=("LO", "HI"),
        help="scan window in degrees (default -20 20)",
    )
    p.add_argument(
        "--direction",
        type=int,
        choices=(1, -1),
        default=1,
        help="sweep direction: 1 towards +θ (left), -1 towards -θ",
    )
    p.add_argument("--seed", type=int, default=1, help="noise seed (1)")
    p.add_argument("--json", metavar="FILE", help="write the samples as JSON")
    p.add_argument("--plot", metavar="FILE", help="write the range and intensity images (PNG)")
    p.add_argument("--calibration", metavar="FILE", help="calibration file (default: shipped)")
    p.set_defaults(func=_lazy("cli.sensor_commands", "scan_command"))

    p = sub.add_parser(
        "demo",
        help="the closed loop: the vehicle drives a world's task on the environment vector",
        description="Runs launch/demo.toml's graph (world, head, calibration, filtering, "
        "features, tracking, planner, vehicle) on the world's [task], prints progress and a "
        "summary, and writes run.mcap, run.png, run.gif and summary.json to --out.",
    )
    p.add_argument("world", nargs="?", help="a world file with a [task] (worlds/demo.toml)")
    p.add_argument(
        "--policy",
        default="active",
        help="the head policy: active (default), or a baseline: forward, sweep or greedy",
    )
    p.add_argument("--controller", default="default", help="the vehicle's planner: default or dwa")
    p.add_argument("--out", default="out/demo", help="where the outputs go (out/demo)")
    p.add_argument(
        "--lockstep",
        action="store_true",
        help="the same stages in this process on a simulated clock, faster than real time",
    )
    p.add_argument(
        "--serial",
        action="store_true",
        help="the head over its serial link: launch/demo_serial.toml against the head's "
        "firmware emulator on a pseudo-terminal (processes only)",
    )
    p.set_defaults(func=_lazy("cli.demo", "demo_command"))

    p = sub.add_parser("bench", help="measure simulation and stage speed (prints figures)")
    p.add_argument("--scans", type=int, default=200, help="simulator sweeps to time (200)")
    p.add_argument("--obstacles", type=int, default=50, help="obstacles in the world (50)")
    p.add_argument("--seed", type=int, default=0, help="world and noise seed (0)")
    p.add_argument(
        "--pipeline-scans",
        type=int,
        default=3000,
        help="scans through the pipeline for throughput (3000)",
    )
    p.add_argument(
        "--latency-scans",
        type=int,
        default=100,
        help="scans at 10 Hz for latency, in one process and as processes (100)",
    )
    p.add_argument(
        "--cpu-seconds",
        type=float,
        default=15.0,
        help="seconds of the sim graph at 10 Hz for CPU use (15)",
    )
    p.add_argument(
        "--codec-calls",
        type=int,
        default=2000,
        help="timed encodes and decodes per message type (2000)",
    )
    p.add_argument(
        "--hop-round-trips",
        type=int,
        default=2000,
        help="timed round trips per message type between two processes (2000)",
    )
    p.add_argument(
        "--hop-warm-up",
        type=int,
        default=200,
        help="untimed round trips per message type first (200)",
    )
    p.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    p.set_defaults(func=_lazy("cli.bench", "bench_command"))
    bench_sub = p.add_subparsers(dest="bench_what", metavar="[perception|faults|tracking]")
    q = bench_sub.add_parser("perception", help="filtering and features against the truth")
    # 3000 scenes (about 25 s): the NEES tails are binomial fractions, and over the 300
    # scenes of ~280 cylinders their σ is 1.8 %, too coarse for a 2-10 % target.
    q.add_argument("--scenes", type=int, default=3000, help="random scenes (3000)")
    q.add_argument("--seed", type=int, default=0, help="scene and noise seed (0)")
    q.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    q.set_defaults(func=_lazy("cli.bench", "perception_command"))
    q = bench_sub.add_parser(
        "faults", help="restart-to-output per process, and the time to notice a hung one"
    )
    q.add_argument("--trials", type=int, default=3, help="kills per process (3)")
    q.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    q.set_defaults(func=_lazy("cli.bench", "faults_command"))
    q = bench_sub.add_parser(
        "tracking",
        help="tracks and free space in random dynamic scenes, against the truth and a baseline",
        description=_TRACKING_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    q.add_argument(
        "--scenes", type=int, default=8, help="random scenes, 20-40 s of driving each (8)"
    )
    q.add_argument("--seed", type=int, default=0, help="scene and noise seed (0)")
    q.add_argument(
        "--policy",
        choices=("forward", "sweep", "active", "greedy"),
        default="forward",
        help="the planner's head policy (forward)",
    )
    q.add_argument(
        "--max-scene-s", type=float, metavar="S", help="cut each drive at S seconds (60)"
    )
    q.add_argument("--no-baseline", action="store_true", help="skip the Stone Soup baseline")
    q.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    q.add_argument(
        "--plot",
        metavar="FILE",
        help="drive the first scene again and draw its tracks and free space (PNG)",
    )
    q.set_defaults(func=_lazy("cli.bench_tracking", "tracking_command"))

    from cli.evaluate import POLICIES

    p = sub.add_parser(
        "evaluate",
        help="closed-loop runs over many worlds: outcome rates, score, clearance (prints figures)",
        usage=_EVALUATE_USAGE,
        description=_EVALUATE_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "targets",
        nargs="*",
        metavar="WORLD_OR_DIR",
        help="world files or directories; or merge|plot and evaluations' JSON files",
    )
    p.add_argument("--random", type=int, metavar="N", help="N random worlds with tasks")
    p.add_argument("--seed", type=int, metavar="S", help="world and noise seed (0)")
    p.add_argument("--policy", metavar="P", help=f"the head policy: {', '.join(POLICIES)}")
    p.add_argument(
        "--controller",
        metavar="C",
        help="the vehicle controller's planner: default, or dwa (the dynamic window baseline)",
    )
    p.add_argument(
        "--jobs", type=int, metavar="J", help="worker processes (all cores; 1: in this process)"
    )
    p.add_argument("--shard", metavar="K/N", help="only the runs i with i %% N == K - 1")
    p.add_argument("--json", metavar="FILE", help="write the runs and the summary as JSON")
    p.add_argument(
        "--plots", metavar="DIR", help="write success, score, clearance and failure PNGs here"
    )
    p.add_argument(
        "--cluster",
        metavar="ADDRESS",
        help="run on a Dask distributed scheduler (pip install '.[cluster]')",
    )
    p.set_defaults(func=_lazy("cli.evaluate", "evaluate_command"))

    p = sub.add_parser(
        "launch",
        help="start and supervise a process graph",
        description="Start the processes of a launch file (on this host), "
        "restart them on failure, stop them cleanly on Ctrl-C.",
    )
    p.add_argument("file", help="launch file (TOML), e.g. launch/sim.toml")
    p.add_argument("--host", help="start only the processes on this host")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.add_argument(
        "--json",
        metavar="FILE",
        help="write a summary: exit codes, restarts, per-topic counts, rates and gaps",
    )
    p.add_argument("--record", metavar="FILE.mcap", help="record every bus message to MCAP")
    p.add_argument(
        "--runtime-dir",
        metavar="DIR",
        help="runtime directory for ipc sockets (default: a new private one)",
    )
    p.set_defaults(func=cmd_launch)

    p = sub.add_parser(
        "systemd",
        help="write systemd units for one host's part of a launch file's graph",
        description="Writes a .service per process on --host (run as the launcher runs it, "
        "with its restart limits, start timeout and hang watchdog), a .target for them all, "
        "and the resolved graph.json they read; prints the install steps (docs/deploy.md).",
    )
    p.add_argument("launch", metavar="LAUNCH", help="launch file (TOML), e.g. launch/robot.toml")
    p.add_argument("--host", required=True, help="the host whose processes to write")
    p.add_argument("--out", required=True, metavar="DIR", help="where to write the units")
    p.add_argument("--user", default="sensor-agent", help="user the services run as (sensor-agent)")
    p.add_argument("--group", help="their group (default: the user's name)")
    p.add_argument(
        "--python",
        default=sys.executable,
        help="the installed interpreter that runs them (default: this one)",
    )
    p.add_argument(
        "--etc",
        default="/etc/sensor-agent",
        metavar="DIR",
        help="where graph.json is installed, as DIR/GRAPH/graph.json (/etc/sensor-agent)",
    )
    p.add_argument(
        "--keys-dir", metavar="DIR", help="where the CURVE keys are on the host (DIR/GRAPH/keys)"
    )
    p.set_defaults(func=_lazy("cli.systemd", "systemd_command"))

    p = sub.add_parser(
        "warm-up",
        help="compile the compiled kernels into their caches (once, at install)",
        description="Compiles every numba kernel the stages use and caches it beside its "
        "module, so that processes (and services that may not write there) start without "
        "compiling. About a minute.",
    )
    p.set_defaults(func=cmd_warm_up)

    p = sub.add_parser(
        "soak",
        help="the closed loop over the serial emulator while agent processes are killed",
        description="Runs launch/demo_serial.toml against the head emulator for --minutes, "
        "killing a random process of the agent every --kill-every seconds; measures wheel "
        "commands that would move on stale data, memory and descriptor growth, restarts.",
    )
    p.add_argument("--minutes", type=float, default=10.0, help="how long (10)")
    p.add_argument("--kill-every", type=float, default=20.0, metavar="S", help="seconds (20)")
    p.add_argument("--seed", type=int, default=0, help="which processes are killed (0)")
    p.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    p.set_defaults(func=_lazy("cli.soak", "soak_command"))

    p = sub.add_parser(
        "fuzz",
        help="random and mutated messages into every stage's inputs (0 crashes expected)",
        description="Builds the closed loop's stages (world, head, calibration, filtering, "
        "features, tracking, planner, vehicle), warms them up on the demo world, then sends "
        "each stage input --messages random, byte-mutated or field-mutated messages, decoded "
        "and validated as a process does; counts rejections by kind and crashes (exit 1).",
    )
    p.add_argument("--messages", type=int, default=2000, help="messages per stage input (2000)")
    p.add_argument("--seed", type=int, default=0, help="the mutations' seed (0)")
    p.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    p.set_defaults(func=_lazy("cli.fuzz", "fuzz_command"))

    p = sub.add_parser(
        "head-emulator",
        help="the head's firmware on a pseudo-terminal, backed by the simulator",
        description="Prints the port (a pseudo-terminal) and speaks docs/head-protocol.md "
        "there: handshake, commands acknowledged or refused, status at 10 Hz, clock probes, "
        "the simulated head's samples; the laser's safety state machine at 1 kHz.",
    )
    p.add_argument("--world", default="worlds/demo.toml", help="world file (worlds/demo.toml)")
    p.add_argument("--seed", type=int, default=0, help="the sensor noise's seed (0)")
    p.add_argument(
        "--faults",
        metavar="SPEC",
        help="comma-separated: stall@T, slow@T, silent@T, garbage@T, drop=P, flip=P, "
        "truncate=P (frames cut short), baud=N (the head's UART rate)",
    )
    p.add_argument(
        "--link", metavar="PATH", help="also make PATH a symlink to the port (for a launch file)"
    )
    p.add_argument(
        "--truth",
        metavar="ENDPOINT",
        help="a graph's world endpoint (ipc://RUNTIME/world.pub): the vehicle's true motion",
    )
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.set_defaults(func=_lazy("cli.head_emulator", "head_emulator_command"))

    p = sub.add_parser(
        "safety-test",
        help="the laser's safety state machine under injected faults (time to laser off)",
        description="For each fault (mirror stall, mirror slow, heartbeat lost, bad command), "
        "--trials runs of the head firmware's control loop with the fault injected at a random "
        "time; prints the time from the fault to the laser off (p50, max, failures over "
        "100 ms) and the trips of as many fault-free runs. Exit status 1 on any failure.",
    )
    p.add_argument("--trials", type=int, default=1000, help="trials per fault (1000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the trials (0)")
    p.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    p.set_defaults(func=_lazy("cli.safety_test", "safety_test_command"))

    p = sub.add_parser(
        "export",
        help="write a recording with Foxglove's schemas, to open in the Foxglove app",
        description="Reads RUN.mcap (launch --record, demo's run.mcap), decodes every message "
        "and writes OUT.mcap with Foxglove's well-known schemas: scans as laser scans and point "
        "clouds, tracks and the environment vector as scene entities with their covariance "
        "ellipses, the vehicle's frames as transforms (docs/viewer.md). --foxglove, the only "
        "format so far, is required. Needs the Foxglove SDK: pip install '.[viewer]'.",
    )
    p.add_argument("input", metavar="RUN.mcap", help="a recording")
    p.add_argument("output", metavar="OUT.mcap", help="the file to write (replaced if there)")
    p.add_argument(
        "--foxglove", action="store_true", help="Foxglove's well-known schemas (required)"
    )
    p.set_defaults(func=_lazy("cli.viewer", "export_command"))

    p = sub.add_parser(
        "view",
        help="serve a running graph to the Foxglove app (a WebSocket server)",
        description="Attaches to a running graph as echo does, converts its messages as "
        "export --foxglove does and serves them on a Foxglove WebSocket server; prints the "
        "ws:// URL to open in the Foxglove app. Ctrl-C stops. Needs the Foxglove SDK: "
        "pip install '.[viewer]'.",
    )
    p.add_argument(
        "--graph",
        metavar="NAME",
        help="running graph: its name, its runtime directory, or (run as services) its "
        "graph.json (default: the newest running graph)",
    )
    p.add_argument(
        "--host", default="127.0.0.1", help="address to serve on (127.0.0.1; 0.0.0.0: all)"
    )
    p.add_argument("--port", type=int, default=8765, help="port to serve on (8765; 0: any free)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.set_defaults(func=_lazy("cli.viewer", "view_command"))

    p = sub.add_parser("keys", help="make CURVE keys for tcp:// endpoints")
    p.add_argument("dir", help="directory to create")
    p.add_argument(
        "--force", action="store_true", help="replace keys already there (other hosts lose access)"
    )
    p.set_defaults(func=cmd_keys)

    from cli import introspect

    introspect.add_commands(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    for name, least in (
        ("samples", 10),
        ("sweeps", 1),
        ("planes", 4),
        ("eval_sweeps", 1),
        ("scans", 1),
        ("obstacles", 1),
        ("trials", 1),
    ):
        value = getattr(args, name, None)
        if value is not None and value < least:
            print(
                f"sensor-agent: --{name.replace('_', '-')} must be at least {least}, got {value}",
                file=sys.stderr,
            )
            return 2
    try:
        return int(args.func(args))
    except SensorAgentError as exc:
        print(f"sensor-agent: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("sensor-agent: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
