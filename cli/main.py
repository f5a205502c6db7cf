"""``sensor-agent``: the command line of the LEP active-sensing agent.

Subcommands
-----------
characterise  reproduce the chapter's sensor characterisation (section 6.6-6.7) from simulation
calibrate     scan calibration targets, build the range look-up table, report before/after
scan          one sweep of the simulated head over a world file
bench         measure how fast the simulation and the agent's stages run
launch        start a process graph from a launch file and supervise it
keys          make CURVE keys for tcp:// endpoints

Bad input (a world or calibration file, an out-of-range head command) prints one line naming
the problem and exits with status 2.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from agent.calibration import Calibration, load_default_calibration
from agent.characterisation import (
    CalibrationSettings,
    CharacterisationResult,
    ErrorGrid,
    characterise,
    evaluate_calibration,
    run_calibration,
    scan_calibration_planes,
)
from agent.errors import SensorAgentError
from agent.motion import StaticPose, head_origin
from agent.params import nominal_sensor, simulated_head
from agent.scanning import ScanWindow
from agent.simulator import SensorSimulator
from agent.world import load_world

log = logging.getLogger("sensor-agent")


# ----------------------------------------------------------------------------------- helpers
def _jsonable(value: Any) -> Any:
    """Numpy arrays and scalars to lists and floats; NaN and infinities to null."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.bool_ | bool):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        f = float(value)
        return f if math.isfinite(f) else None
    return value


def _write_json(path: Path, payload: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_jsonable(payload), indent=1, allow_nan=False) + "\n")
    print(f"wrote {path}")


@contextmanager
def _progress(description: str) -> Iterator[Callable[[int, int], None]]:
    """A progress bar on stderr (only when it is a terminal)."""
    from tqdm import tqdm

    bar = tqdm(desc=description, total=1, disable=None, leave=False, file=sys.stderr)

    def update(done: int, total: int) -> None:
        bar.total = total
        bar.n = done
        bar.refresh()

    try:
        yield update
    finally:
        bar.close()


def _load_calibration(path: str | None) -> Calibration:
    return load_default_calibration() if path is None else Calibration.load(path)


# ------------------------------------------------------------------------------ characterise
def _print_characterisation(res: CharacterisationResult) -> None:
    d = res.as_dict()
    fit, true, err = d["fit"], d["true"], d["errors"]
    print("Sensor characterisation (least squares on logarithmic plots, section 6.6)")
    print(
        f"  signal constant S   {fit['S_Am2']:.4g} A·m²   true {true['S_Am2']:.4g}"
        f"   ({err['S_pct']:+.2f} %)   slope {fit['slope_signal']:+.3f} (theory -2)"
    )
    print(
        f"  noise current I_n   {1e12 * fit['I_n_A']:.2f} pA      true "
        f"{1e12 * true['I_n_A']:.2f}    ({err['I_n_pct']:+.2f} %)   slope "
        f"{fit['slope_position']:+.3f} (theory +2)"
    )
    print(
        f"  gain constant fd    {fit['fd_m2']:.5f} m²    true {true['fd_m2']:.5f}"
        f"   ({err['fd_pct']:+.2f} %)   slope {fit['slope_range']:+.3f} (theory +4)"
    )
    print(f"  constant T          {fit['T_per_m3']:.4g} m⁻³")
    n = d["noise"]
    print(
        f"  noise density       {1e12 * n['measured_density_A_per_rtHz']:.3f} pA/√Hz measured,"
        f" {1e12 * n['theoretical_density_A_per_rtHz']:.3f} theoretical: "
        f"{n['percent_above_theoretical']:.0f} % above"
    )
    print("Table 1: standard deviation of range")
    print("  range (m)   SD (cm)   SD (% of range)   chapter SD (cm)   ratio")
    for row in d["table"]:
        print(
            f"  {row['range_m']:8.2f}   {row['sd_cm']:7.3f}   {row['sd_pct']:15.3f}   "
            f"{row['paper_sd_cm']:15.3f}   {row['sd_cm'] / row['paper_sd_cm']:5.2f}"
        )
    e = res.edge_accuracy
    print(
        f"Accuracy at the ±20° scan edges relative to the centre (at {e['range_m']:g} m): "
        f"{e['ratio']:.3f} (left {e['left_ratio']:.3f}, right {e['right_ratio']:.3f}; "
        f"cos³20° = {e['cos3_theta']:.3f})"
    )


def cmd_characterise(args: argparse.Namespace) -> int:
    head = simulated_head()
    calibration = _load_calibration(args.calibration)
    rng = np.random.default_rng(args.seed)
    with _progress("characterising") as progress:
        res = characterise(calibration, head, rng, args.samples, progress=progress)
    _print_characterisation(res)
    if args.plots is not None:
        from cli import plots

        out = Path(args.plots)
        out.mkdir(parents=True, exist_ok=True)
        curves = scan_calibration_planes(head, rng, (0.5, 0.6, 0.7, 0.8, 0.9, 1.0), 2)
        written = [
            plots.calibration_curves(
                curves,
                head.detector_centre_m,
                head.detector_length_m,
                out / "fig6_7_calibration_curves.png",
            ),
            plots.signal_vs_range(res, out / "fig6_8_signal_vs_range.png"),
            plots.resolution_vs_range(res, out / "fig6_9_resolution_vs_range.png"),
            plots.range_histogram(res, out / "fig6_10_histogram_1m.png"),
            plots.sigma_vs_range(res, out / "fig6_11_sd_vs_range.png"),
        ]
        for path in written:
            print(f"wrote {path}")
    if args.json is not None:
        payload = res.as_dict()
        payload["samples_per_range"] = args.samples
        payload["seed"] = args.seed
        _write_json(Path(args.json), payload)
    return 0


# -------------------------------------------------------------------------------- calibrate
def _print_grid(title: str, grid: ErrorGrid) -> None:
    print(title)
    edges = np.degrees(grid.angle_bin_edges_rad)
    centres = 0.5 * (edges[1:] + edges[:-1])
    print(
        "  range (m) | bias (mm) and bias/σ per scan-angle bin (deg): "
        + " ".join(f"{c:+.0f}" for c in centres)
    )
    for i, r in enumerate(grid.ranges_m):
        cells = " ".join(f"{b:8.3f}" for b in grid.bias_mm[i])
        sig = " ".join(f"{z:+6.2f}" for z in grid.bias_sigma[i])
        print(f"  {r:5.2f} mm: {cells}\n        σ:  {sig}")
    d = grid.as_dict()
    print(
        f"  worst |bias| {d['max_abs_bias_mm']:.3f} mm, {d['max_abs_bias_sigma']:.3f} σ; "
        f"RMS/σ {np.nanmin(grid.rms_sigma):.2f}..{np.nanmax(grid.rms_sigma):.2f}"
    )


def cmd_calibrate(args: argparse.Namespace) -> int:
    head = simulated_head()
    rng = np.random.default_rng(args.seed)
    settings = CalibrationSettings(n_planes=args.planes, n_sweeps=args.sweeps)
    started = time.perf_counter()
    with _progress("scanning calibration targets") as progress:
        calibration, res = run_calibration(head, rng, settings, progress)
    built_s = time.perf_counter() - started
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    calibration.save(out)
    print(
        f"wrote {out} ({settings.n_planes} planes x {settings.n_sweeps} sweeps, "
        f"{built_s:.1f} s); characterised S {res.fit_S_Am2:.4g} A·m², "
        f"I_n {1e12 * res.fit_I_n_A:.2f} pA, fd {res.fit_fd_m2:.5f} m²"
    )
    with _progress("evaluating") as progress:
        after, before = evaluate_calibration(
            calibration, head, rng, n_sweeps=args.eval_sweeps, progress=progress
        )
    _print_grid(
        "Range error before calibration (nominal equations: fd = f·d, drawn detector, linear LEP):",
        before,
    )
    _print_grid("Range error after calibration (look-up table):", after)
    if args.json is not None:
        _write_json(
            Path(args.json),
            {
                "calibration_file": str(out),
                "seed": args.seed,
                "planes": settings.n_planes,
                "sweeps_per_plane": settings.n_sweeps,
                "characterisation": res.as_dict(),
                "before": before.as_dict(),
                "after": after.as_dict(),
            },
        )
    return 0


# ------------------------------------------------------------------------------------- scan
def cmd_scan(args: argparse.Namespace) -> int:
    head = simulated_head()
    world = load_world(args.world)
    calibration = _load_calibration(args.calibration)
    if args.pose is not None:
        x, y, yaw_deg = args.pose
        pose = StaticPose(x, y, math.radians(yaw_deg))
    else:
        pose = StaticPose(*world.vehicle_pose)
    window = ScanWindow.full(head) if args.window is None else ScanWindow.from_degrees(*args.window)
    sim = SensorSimulator(world, head, np.random.default_rng(args.seed))
    raw, truth = sim.sweep(
        window, direction=args.direction, pan_rad=math.radians(args.pan), trajectory=pose
    )
    scan = calibration.calibrate_scan(raw)
    x, y, yaw = pose.poses_at(scan.time_s)
    origin = head_origin(x, y, yaw, nominal_sensor().mount_offset_m)
    heading = yaw + scan.pan_rad + scan.scan_angle_rad
    valid = np.isfinite(scan.range_m)
    print(
        f"scan of {args.world}: {len(raw)} samples over "
        f"[{math.degrees(window.low_rad):.1f}, {math.degrees(window.high_rad):.1f}] deg at pan "
        f"{args.pan:.1f} deg, {1e3 * (raw.time_s[-1] - raw.time_s[0]):.1f} ms; "
        f"{int(valid.sum())} readings, {int((~truth.visible).sum())} samples with the return "
        "path blocked"
    )
    if valid.any():
        print(
            f"  range {np.nanmin(scan.range_m):.3f}..{np.nanmax(scan.range_m):.3f} m, "
            f"median σ {1e3 * np.nanmedian(scan.sigma_m):.2f} mm"
        )
    if args.json is not None:
        samples = {
            "time_s": scan.time_s,
            "scan_angle_rad": scan.scan_angle_rad,
            "pan_rad": scan.pan_rad,
            "image_position_norm": scan.image_position_norm,
            "intensity_A": scan.intensity_A,
            "range_m": scan.range_m,
            "sigma_m": scan.sigma_m,
            "beam_origin_xy": origin,
            "beam_heading_rad": heading,
            "truth_range_m": truth.range_m,
            "truth_visible": truth.visible,
        }
        _write_json(
            Path(args.json),
            {
                "world": str(args.world),
                "seed": args.seed,
                "pose": [pose.x_m, pose.y_m, pose.yaw_rad],
                "window_rad": [window.low_rad, window.high_rad],
                "direction": args.direction,
                "samples": samples,
            },
        )
    if args.plot is not None:
        from cli import plots

        path = Path(args.plot)
        path.parent.mkdir(parents=True, exist_ok=True)
        plots.scan_images(scan, truth.range_m, f"scan of {Path(args.world).name}", path)
        print(f"wrote {path}")
    return 0


# ------------------------------------------------------------------------------------ bench
def cmd_bench(args: argparse.Namespace) -> int:
    from cli.bench import run_bench

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
        _write_json(Path(args.json), figures)
    return 0


# ----------------------------------------------------------------------------------- launch
def _print_summary(summary: dict[str, Any]) -> None:
    print(f"graph {summary['graph']} stopped: {summary['stop_reason']}")
    for name, p in summary["processes"].items():
        print(f"  {name:12s} exit {p['exit_code']!s:>4}  restarts {p['restarts']}")
    for topic, t in summary["topics"].items():
        print(
            f"  {topic:16s} {t['count']:7d} msgs  {t['rate_hz']:8.2f} Hz  "
            f"max gap {t['max_gap_s']:.3f} s"
        )


def cmd_launch(args: argparse.Namespace) -> int:
    from agent.launch import load_launch
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
        from agent.recording import Recorder

        recorder = Recorder(args.record)
    launcher = Launcher(graph, host=args.host, runtime_dir=args.runtime_dir, recorder=recorder)
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
        _write_json(Path(args.json), summary)
    return status


def cmd_keys(args: argparse.Namespace) -> int:
    from agent.bus import create_keys

    directory = create_keys(args.dir)
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
    p.set_defaults(func=cmd_characterise)

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
    p.set_defaults(func=cmd_calibrate)

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
    p.set_defaults(func=cmd_scan)

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
        "--latency-scans", type=int, default=100, help="scans at 10 Hz for latency (100)"
    )
    p.add_argument(
        "--cpu-seconds",
        type=float,
        default=5.0,
        help="seconds of the sim graph at 10 Hz for CPU use (5)",
    )
    p.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    p.set_defaults(func=cmd_bench)

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

    p = sub.add_parser("keys", help="make CURVE keys for tcp:// endpoints")
    p.add_argument("dir", help="directory to create")
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
