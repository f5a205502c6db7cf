"""``sensor-agent demo [WORLD] [--policy P] [--out DIR] [--lockstep | --serial]``: the loop.

The whole graph of ``launch/demo.toml`` (world, head, calibration, filtering, features,
tracking, planner, vehicle) drives the world's ``[task]`` (default ``worlds/demo.toml``: a
hall with movers crossing the way, and a docking plate at the far end). By default every
stage runs as its own process under the launcher, the bus recorded; ``--lockstep`` runs the
same stages in this process on a simulated clock, faster than real time, recording what
passes between them the same way; ``--serial`` runs ``launch/demo_serial.toml`` instead,
the head process talking to the head's firmware emulator (``sensor-agent head-emulator``,
started here on a pseudo-terminal over the same world, fed the graph's true vehicle
motion) over the serial protocol, to compare the outcome with the simulated backend's.
Either way the outputs come from the recording:

* ``run.mcap``: every message of the run (``sensor-agent replay`` plays it back);
* ``run.png``: the true world, the vehicle's true and odometry paths, the environment vector
  every few seconds mapped into the world through the odometry's error (obstacles with 3σ
  ellipses, free space), and where the head looked over time;
* ``run.gif``: the run as an animation, one frame per half second;
* ``summary.json``: the run's record, as ``sensor-agent evaluate`` writes each run.

Progress (the controller's mode, the distance to the goal) is printed as the run goes, and a
summary at the end.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agent.errors import ConfigError, SensorAgentError
from agent.runtime.messages import (
    EnvironmentVector,
    HeadCommand,
    HeadState,
    Message,
    Odometry,
    WorldTruth,
    decode,
)

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_WORLD = ROOT / "worlds" / "demo.toml"
LAUNCH_FILE = ROOT / "launch" / "demo.toml"
SERIAL_LAUNCH_FILE = ROOT / "launch" / "demo_serial.toml"
FRAME_EVERY_S = 0.5  # the animation's step
SNAPSHOT_EVERY_S = 6.0  # the plot's environment vectors
STILL_S = 2.0  # multi-process: stopped this long with the task done, the run is over


@dataclass
class RunLog:
    """What the plot, the animation and the summary need, from the run's messages."""

    truth: list[tuple[float, float, float, float]] = field(default_factory=list)  # t, x, y, yaw
    movers: list[np.ndarray] = field(default_factory=list)
    odometry: list[tuple[float, float, float, float]] = field(default_factory=list)
    environments: list[EnvironmentVector] = field(default_factory=list)
    head: list[tuple[float, float, float, float]] = field(default_factory=list)  # t, pan, lo, hi
    # The planner's choices where it weighed them: t, pan, window centre, bits, head time.
    choices: list[tuple[float, float, float, float, float]] = field(default_factory=list)
    last_truth: WorldTruth | None = None
    _next_env_s: float = -math.inf

    def add(self, msg: Message) -> None:
        t = msg.header.stamp_s
        if isinstance(msg, WorldTruth):
            self.truth.append((t, msg.x_m, msg.y_m, msg.yaw_rad))
            self.movers.append(np.asarray(msg.mover_xy, dtype=np.float64).reshape(-1, 2))
            self.last_truth = msg
        elif isinstance(msg, Odometry):
            self.odometry.append((t, msg.x_m, msg.y_m, msg.yaw_rad))
        elif isinstance(msg, EnvironmentVector) and msg.sensor_ok and t >= self._next_env_s:
            self._next_env_s = t + FRAME_EVERY_S
            self.environments.append(msg)
        elif isinstance(msg, HeadState):
            self.head.append((t, msg.pan_rad, msg.window_low_rad, msg.window_high_rad))
        elif isinstance(msg, HeadCommand) and msg.cost_s > 0.0:
            centre = msg.pan_rad + 0.5 * (msg.window_low_rad + msg.window_high_rad)
            self.choices.append((t, msg.pan_rad, centre, msg.utility_bits, msg.cost_s))


# ------------------------------------------------------------------------------- running
def run_lockstep(world: Any, policy: str, controller: str, out: Path, log: RunLog) -> Any:
    """The closed loop in this process (:func:`cli.closed_loop.run_closed_loop`), every
    message recorded to ``out/run.mcap`` and logged."""
    from agent.runtime.messages import stamp_ns
    from agent.runtime.recording import Recorder
    from cli.closed_loop import run_closed_loop

    printer = _Progress(world.task)
    with Recorder(out / "run.mcap") as recorder:

        def observe(t: float, topic: str, msg: Message) -> None:
            recorder.write(topic, msg.to_wire(), stamp_ns(t))
            log.add(msg)
            if isinstance(msg, WorldTruth):
                printer.truth(msg)

        result = run_closed_loop(
            world, world.task, policy, controller, seed=0, observe=observe,
            progress=printer.mode,
        )  # fmt: skip
    return result


def run_processes(
    world_path: Path,
    world: Any,
    policy: str,
    controller: str,
    out: Path,
    log: RunLog,
    serial: bool = False,
) -> None:
    """The graph as processes under the launcher, recorded to ``out/run.mcap``; ends when the
    vehicle collides, or has done its task (scored on truth) and stood still for
    :data:`STILL_S`, or at the task's time limit. The log is filled from the recording.
    ``serial``: the head over its serial link to the firmware emulator (module docstring)."""
    import sys

    from agent.runtime.recording import read_recording
    from agent.scoring.closed_loop import task_success
    from cli.bench_graph import GraphUnderTest

    time_limit_s = world.task.time_limit_s

    work = Path(tempfile.mkdtemp(prefix="lepdemo"))
    emulator: subprocess.Popen[bytes] | None = None
    try:
        link = work / "head"
        source = SERIAL_LAUNCH_FILE if serial else LAUNCH_FILE
        text = source.read_text().replace('"../', f'"{ROOT}/')
        text = text.replace('"/tmp/lep-head"', json.dumps(str(link)))
        text = text.replace(f'"{ROOT}/worlds/demo.toml"', json.dumps(str(world_path.resolve())))
        text = text.replace('policy = "active"', f"policy = {json.dumps(policy)}")
        text = text.replace('planner = "default"', f"planner = {json.dumps(controller)}")
        launch = work / "demo.toml"
        launch.write_text(text)
        record = out / "run.mcap"
        printer = _Progress(None)
        with GraphUnderTest(launch, play=None, listen=("world_truth",), record=record) as graph:
            if serial:
                # The firmware over the same world, fed the graph's true motion; the head
                # process opens the port with backoff until it appears.
                world_endpoint = graph.graph.publishers()["world_truth"][1]
                with (work / "emulator.log").open("wb") as emulator_log:
                    emulator = subprocess.Popen(
                        [sys.executable, "-m", "cli.main", "head-emulator", "--world",
                         str(world_path.resolve()), "--link", str(link), "--truth",
                         world_endpoint, "--duration", f"{time_limit_s + 30.0:.0f}"],
                        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=emulator_log,
                    )  # fmt: skip
            bus = graph.listen()
            started = time.monotonic()
            still_since: float | None = None
            while time.monotonic() - started < time_limit_s + 5.0:
                for _, payload in bus.poll(0.1):
                    msg = decode(payload)
                    if not isinstance(msg, WorldTruth):
                        continue
                    printer.truth(msg)
                    still = abs(msg.speed_m_s) < 1e-3 and abs(msg.yaw_rate_rad_s) < 1e-3
                    # Stopped where the task is done (a vehicle that waits, looks or yields
                    # stands still too, and its run goes on).
                    done = still and task_success(
                        world.task, (msg.x_m, msg.y_m, msg.yaw_rad), world=world
                    )
                    still_since = (still_since or time.monotonic()) if done else None
                    settled = still_since is not None and time.monotonic() - still_since >= STILL_S
                    if msg.collision or settled:
                        time_limit_s = 0.0
                if graph.proc.poll() is not None:
                    break
                if emulator is not None and emulator.poll() is not None:
                    tail = (work / "emulator.log").read_text(errors="replace").strip()
                    last = tail.splitlines()[-1] if tail else "(no output)"
                    raise SensorAgentError(
                        f"demo: the head emulator exited with status {emulator.returncode} "
                        f"before the run ended: {last}"
                    )
        _stop_emulator(emulator)
        for recorded in read_recording(record):
            try:
                log.add(decode(recorded.payload))
            except Exception:
                continue
    finally:
        _stop_emulator(emulator)
        shutil.rmtree(work, ignore_errors=True)


def _stop_emulator(emulator: subprocess.Popen[bytes] | None) -> None:
    """Stop the head emulator if it still runs: SIGTERM, then SIGKILL after 10 s."""
    if emulator is None or emulator.poll() is not None:
        return
    emulator.terminate()
    try:
        emulator.wait(10)
    except subprocess.TimeoutExpired:
        emulator.kill()
        emulator.wait(10)


class _Progress:
    """Prints a line every few simulated seconds: time, mode, distance to the goal."""

    def __init__(self, task: Any) -> None:
        self.task = task
        self.next_s = 0.0
        self.t0: float | None = None
        self.last_mode = ""

    def mode(self, t: float, mode: str) -> None:
        self.last_mode = mode

    def truth(self, msg: WorldTruth) -> None:
        t = msg.header.stamp_s
        if self.t0 is None:
            self.t0 = t
        t -= self.t0
        if t < self.next_s:
            return
        self.next_s = t + 5.0
        where = f"x {msg.x_m:6.2f} m, y {msg.y_m:6.2f} m, speed {msg.speed_m_s:4.2f} m/s"
        mode = f", {self.last_mode}" if self.last_mode else ""
        clear = f", clearance {msg.clearance_m:4.2f} m" if math.isfinite(msg.clearance_m) else ""
        print(f"  t {t:6.1f} s: {where}{clear}{mode}", flush=True)


# ------------------------------------------------------------------------------- figures
def write_figures(world: Any, log: RunLog, out: Path, title: str) -> list[Path]:
    """``run.png`` and ``run.gif`` from the log."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation, PillowWriter
    from matplotlib.patches import Circle, Ellipse, Polygon

    from agent.scoring.frames import PoseHistory
    from cli.bench_tracking import _snapshot

    paths = []
    if not log.truth:
        return paths
    truth = np.array(log.truth)
    odom = np.array(log.odometry) if log.odometry else np.zeros((0, 4))
    true_poses, odom_poses = PoseHistory(), PoseHistory()
    for row in truth:
        true_poses.add(*row)
    for row in odom:
        odom_poses.add(*row)
    t0 = truth[0, 0]

    def world_axes(ax: Any) -> None:
        for a, b in zip(world.segments_start, world.segments_end, strict=True):
            ax.plot([a[0], b[0]], [a[1], b[1]], color="0.5", lw=1.5)
        for c, r in zip(world.circles_center, world.circles_radius, strict=True):
            ax.add_patch(Circle((float(c[0]), float(c[1])), float(r), color="0.75"))
        if world.task is not None:
            ax.plot(*world.task.goal, "*", color="tab:red", ms=12, label="goal")
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")

    def outline(pose: np.ndarray) -> np.ndarray:
        c, s = math.cos(pose[2]), math.sin(pose[2])
        corners = np.array([[0.4, 0.3], [-0.4, 0.3], [-0.4, -0.3], [0.4, -0.3]])
        return corners @ np.array([[c, s], [-s, c]]) + pose[:2]

    def draw_environment(ax: Any, env: EnvironmentVector, colour: Any, alpha: float) -> None:
        t = env.header.stamp_s
        true_pose, odom_pose = true_poses.at(t), odom_poses.at(t)
        if true_pose is None or odom_pose is None:
            return
        snap = _snapshot(env, true_pose, odom_pose)
        known = snap.free_m > 0
        ends = snap.centre_xy + snap.free_m[:, None] * np.stack(
            [np.cos(snap.bearing_rad), np.sin(snap.bearing_rad)], axis=1
        )
        if known.any():
            poly = np.vstack([snap.centre_xy, np.where(known[:, None], ends, snap.centre_xy)])
            ax.fill(poly[:, 0], poly[:, 1], color="tab:green", alpha=0.15 * alpha, lw=0)
        for xy, cov in zip(snap.obstacle_xy, snap.obstacle_cov, strict=True):
            w, v = np.linalg.eigh(0.5 * (cov + cov.T))
            w = np.sqrt(np.maximum(w, 0.0)) * 3.0
            angle = math.degrees(math.atan2(v[1, 1], v[0, 1]))
            ax.add_patch(
                Ellipse(
                    tuple(xy),
                    2 * max(w[1], 0.02),
                    2 * max(w[0], 0.02),
                    angle=angle,
                    fill=False,
                    color=colour,
                    lw=1,
                    alpha=alpha,
                )
            )

    # The plot: the map, and where the head looked over time.
    fig, (ax, ax2) = plt.subplots(
        2, 1, figsize=(8.0, 8.6), gridspec_kw={"height_ratios": [3.2, 1.0]}
    )
    world_axes(ax)
    movers = np.array(log.movers) if log.movers and log.movers[0].size else None
    if movers is not None:
        for j in range(movers.shape[1]):
            ax.plot(movers[:, j, 0], movers[:, j, 1], ":", color="tab:purple", lw=1)
    ax.plot(truth[:, 1], truth[:, 2], "-", color="k", lw=1.2, label="true path")
    if odom.size:
        ax.plot(odom[:, 1], odom[:, 2], "--", color="tab:orange", lw=1, label="odometry")
    snaps = []
    next_s = -math.inf
    for env in log.environments:
        if env.header.stamp_s >= next_s:
            snaps.append(env)
            next_s = env.header.stamp_s + SNAPSHOT_EVERY_S
    colours = plt.cm.viridis(np.linspace(0.0, 0.9, max(1, len(snaps))))
    for env, colour in zip(snaps, colours, strict=False):
        draw_environment(ax, env, colour, 1.0)
    ax.add_patch(Polygon(outline(truth[-1, 1:]), closed=True, fill=False, color="k"))
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(title, fontsize=9)
    if log.head:
        head = np.array(log.head)
        th = head[:, 0] - t0
        ax2.plot(th, np.degrees(head[:, 1]), "-", color="tab:blue", label="pan")
        ax2.fill_between(th, np.degrees(head[:, 1] + head[:, 2]),
                         np.degrees(head[:, 1] + head[:, 3]), color="tab:blue", alpha=0.2,
                         step="post", label="scan window")  # fmt: skip
        ax2.set_ylim(-115, 115)
    if log.choices:
        # Why it looked there: each choice at its window's centre, coloured by the winning
        # action's information per second of head time (the active planner's objective).
        ch = np.array(log.choices)
        rate = ch[:, 3] / ch[:, 4]
        dots = ax2.scatter(
            ch[:, 0] - t0, np.degrees(ch[:, 2]), c=rate, s=9, cmap="magma_r", zorder=3,
            vmin=0.0, vmax=float(np.percentile(rate, 95)) if rate.size else 1.0,
            label="chosen: bits / s of head time",
        )  # fmt: skip
        fig.colorbar(dots, ax=ax2, pad=0.01, label="bits / s")
    ax2.set_xlabel("time (s)")
    ax2.set_ylabel("where the head looked (°)")
    ax2.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    png = out / "run.png"
    fig.savefig(png, dpi=110)
    plt.close(fig)
    paths.append(png)

    # The animation: a frame every FRAME_EVERY_S.
    fig, ax = plt.subplots(figsize=(7.0, 4.6))
    times = truth[:, 0]
    frames = np.arange(times[0], times[-1] + 1e-9, FRAME_EVERY_S)
    env_times = np.array([e.header.stamp_s for e in log.environments])

    def frame(t: float) -> None:
        ax.clear()
        world_axes(ax)
        i = int(np.clip(np.searchsorted(times, t), 0, len(times) - 1))
        ax.plot(truth[: i + 1, 1], truth[: i + 1, 2], "-", color="k", lw=1)
        if movers is not None:
            for c in movers[i]:
                ax.add_patch(Circle(tuple(c), 0.2, color="tab:purple", alpha=0.6))
        if env_times.size:
            k = int(np.searchsorted(env_times, t, side="right")) - 1
            if k >= 0:
                draw_environment(ax, log.environments[k], "tab:red", 1.0)
        ax.add_patch(Polygon(outline(truth[i, 1:]), closed=True, fill=False, color="k"))
        ax.set_title(f"{title}   t = {t - t0:5.1f} s", fontsize=9)

    anim = FuncAnimation(fig, frame, frames=frames, interval=int(FRAME_EVERY_S * 1000))
    gif = out / "run.gif"
    anim.save(gif, writer=PillowWriter(fps=round(1.0 / FRAME_EVERY_S) * 2))
    plt.close(fig)
    paths.append(gif)
    return paths


# ----------------------------------------------------------------------------- command
def summary_record(world: Any, world_label: str, log: RunLog, result: Any | None) -> dict[str, Any]:
    """The run's record (:class:`cli.evaluate.RunRecord`'s JSON), scored against truth.
    Without a lock-step ``result`` (processes) the outcome comes from the recorded truth."""
    from agent.scoring.closed_loop import task_success
    from cli.closed_loop import scored_record

    task = world.task
    truth = np.array(log.truth) if log.truth else np.zeros((0, 4))
    final = tuple(float(v) for v in truth[-1, 1:]) if truth.size else world.vehicle_pose
    last = log.last_truth
    collision_with: str | None = None
    if result is not None:
        outcome, collision_by, time_s = result.outcome, result.collision_by, result.time_s
        min_clearance = result.min_clearance_m
        collision_with = result.collision_with
    else:
        time_s = float(truth[-1, 0] - truth[0, 0]) if truth.size else 0.0
        collision_by = (last.collision or None) if last is not None else None
        min_clearance = last.min_clearance_m if last is not None else math.nan
        if collision_by and last is not None:
            mover = last.collision_obstacle >= world.mover_id_base
            collision_with = "mover" if mover else "static"
        if collision_by:
            outcome = "collision"
        elif task_success(task, final, world=world):
            outcome = "success"
        else:
            outcome = "timeout"
    record = scored_record(
        world, task, world_label, outcome, collision_by, time_s, min_clearance,
        truth[:, 1:3], final, collision_with=collision_with,
    )  # fmt: skip
    return record.to_json()  # type: ignore[no-any-return]


def demo_command(args: argparse.Namespace) -> int:
    """``sensor-agent demo`` (module docstring)."""
    from agent.sim.world_file import load_world
    from cli.evaluate import CONTROLLERS, POLICIES

    world_path = Path(args.world) if args.world else DEFAULT_WORLD
    world = load_world(world_path)
    if world.task is None:
        raise ConfigError(f"{world_path}: no [task] table (the demo drives the world's task)")
    if args.policy not in POLICIES:
        raise ConfigError(
            f"demo: --policy must be one of {', '.join(POLICIES)}, got {args.policy!r}"
        )
    if args.controller not in CONTROLLERS:
        raise ConfigError(
            f"demo: --controller must be one of {', '.join(CONTROLLERS)}, got {args.controller!r}"
        )
    serial = bool(args.serial)
    if serial and args.lockstep:
        raise ConfigError("demo: --serial runs the graph as processes; it takes no --lockstep")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    how = "in lock-step, one process" if args.lockstep else "as processes under the launcher"
    if serial:
        how += ", the head over its serial link to the firmware emulator"
    print(
        f"demo: {world.name or world_path.name}, task {world.task.kind} to "
        f"({world.task.goal[0]:.2f}, {world.task.goal[1]:.2f}), head policy {args.policy}, "
        f"controller {args.controller}, {how}",
        flush=True,
    )
    log = RunLog()
    started = time.perf_counter()
    result = None
    if args.lockstep:
        result = run_lockstep(world, args.policy, args.controller, out, log)
    else:
        run_processes(world_path, world, args.policy, args.controller, out, log, serial)
    wall = time.perf_counter() - started
    record = summary_record(world, str(world_path), log, result)
    record["wall_s"] = wall
    record["policy"], record["controller"] = args.policy, args.controller
    record["head_link"] = "serial" if serial else "simulated"
    (out / "summary.json").write_text(json.dumps(record, indent=2) + "\n")
    title = f"{world.name}: {world.task.kind}, head policy {args.policy} ({record['outcome']})"
    written = write_figures(world, log, out, title)
    dock = ""
    if record.get("dock_error_mm") is not None:
        dock = f", docking error {record['dock_error_mm']:.1f} mm {record['dock_error_deg']:.2f}°"
    print(
        f"demo: {record['outcome']}"
        + (f" (by the {record['collision_by']})" if record.get("collision_by") else "")
        + f" after {record['time_s']:.1f} s simulated ({wall:.1f} s wall), minimum clearance "
        f"{record['min_clearance_m']:.2f} m, score {record['score']:.3f}{dock}"
    )
    for path in [out / "run.mcap", *written, out / "summary.json"]:
        print(f"wrote {path}")
    return 0 if record["outcome"] == "success" else 1
