"""The sensor commands: characterise, calibrate, scan."""

from __future__ import annotations

import argparse
import math
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import numpy as np

from agent.arrays import FloatArray
from agent.calibration.characterisation import CharacterisationResult, characterise
from agent.calibration.evaluation import ErrorGrid, evaluate_calibration
from agent.calibration.procedure import (
    CalibrationSettings,
    run_calibration,
    scan_calibration_planes,
)
from agent.calibration.table import Calibration, load_default_calibration
from agent.kinematics.trajectory import StaticPose, head_origin
from agent.perception.features import Feature, feature_to_dict
from agent.perception.filtering import PoseHistory, SampleFlag
from agent.runtime.messages import stamp_ns
from agent.sensor.params import simulated_head
from agent.sensor.scanning import ScanWindow
from agent.sim.simulator import SensorSimulator
from agent.sim.world_file import load_world
from agent.stages.calibration_stage import CalibrationStage
from agent.stages.features_stage import FeaturesStage
from agent.stages.filtering_stage import FilteringStage
from cli.output import progress_bar, write_json


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


def characterise_command(args: argparse.Namespace) -> int:
    head = simulated_head()
    calibration = _load_calibration(args.calibration)
    rng = np.random.default_rng(args.seed)
    with progress_bar("characterising") as progress:
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
        write_json(Path(args.json), payload)
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


def calibrate_command(args: argparse.Namespace) -> int:
    head = simulated_head()
    rng = np.random.default_rng(args.seed)
    settings = CalibrationSettings(n_planes=args.planes, n_sweeps=args.sweeps)
    started = time.perf_counter()
    with progress_bar("scanning calibration targets") as progress:
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
    with progress_bar("evaluating") as progress:
        after, before = evaluate_calibration(
            calibration, head, rng, n_sweeps=args.eval_sweeps, progress=progress
        )
    _print_grid(
        "Range error before calibration (nominal equations: fd = f·d, drawn detector, linear LEP):",
        before,
    )
    _print_grid("Range error after calibration (look-up table):", after)
    if args.json is not None:
        write_json(
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
# The JSON's note on the features (see agent/features.py for the full conventions).
FEATURE_CONVENTIONS = {
    "frame": (
        "each covariance is over the feature's parameters in the vehicle frame at the scan's "
        "reference time (the last sample's time; REP-103: x forward, y left; metres, "
        "radians); positions in *_world fields are mapped from that frame to the world frame "
        "with vehicle_pose_at_reference, covariances are not"
    ),
    "segment": "covariance over (alpha_rad, rho_m) of the line x cos(alpha) + y sin(alpha) = rho",
    "corner": "covariance over (x_m, y_m)",
    "edge": "covariance over (x_m, y_m); nearer_side: side of the nearer (occluding) surface",
    "cylinder": "covariance over (cx_m, cy_m, r_m)",
}


def pose_to_world(x: float, y: float, yaw: float) -> Callable[[FloatArray], FloatArray]:
    """The map of (k, 2) points in the frame of pose ``(x, y, yaw)`` to the world frame."""
    c, s = math.cos(yaw), math.sin(yaw)
    rotation_t = np.array([[c, s], [-s, c]])  # R(yaw) transposed, for row vectors

    def to_world(points: FloatArray) -> FloatArray:
        world: FloatArray = np.asarray(points, dtype=np.float64) @ rotation_t + np.array([x, y])
        return world

    return to_world


def _count_features(found: list[Feature]) -> str:
    counts = Counter(f.kind for f in found)
    return ", ".join(
        f"{counts[kind]} {kind}{'' if counts[kind] == 1 else 's'}"
        for kind in ("segment", "corner", "edge", "cylinder")
    )


def scan_command(args: argparse.Namespace) -> int:
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
    # The perception stages themselves, as in the agent's graph (and `bench perception`).
    t0, t1 = float(raw.time_s[0]), float(raw.time_s[-1])
    scan = CalibrationStage(calibration).calibrated_message(raw, stamp_ns(t1), 0)
    filtering = FilteringStage(calibration.noise_current_A, mount_offset_m=head.mount_offset_m)
    filtering.poses = PoseHistory.sampled(pose, t0 - 0.05, t1 + 0.02)
    filtered = filtering.filter(scan)
    found = FeaturesStage(calibration.signal_constant_Am2, calibration.noise_current_A).extract(
        filtered
    )
    # The filtered scan's frame: the vehicle's at the reference time, the last sample's.
    x_ref, y_ref, yaw_ref = (float(v[0]) for v in pose.poses_at(np.array([t1])))
    to_world = pose_to_world(x_ref, y_ref, yaw_ref)
    flags, segment = filtered.flag, filtered.segment
    x, y, yaw = pose.poses_at(scan.time_s)
    origin = head_origin(x, y, yaw, head.mount_offset_m)
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
    counts = np.bincount(flags, minlength=len(SampleFlag))
    print(
        "  filtered: "
        + ", ".join(f"{counts[f]} {f.name.lower()}" for f in SampleFlag)
        + f"; {int(segment.max(initial=-1)) + 1} segments"
    )
    print(f"  features: {_count_features(found)}")
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
            "flag": flags,
            "segment": segment,
        }
        write_json(
            Path(args.json),
            {
                "world": str(args.world),
                "seed": args.seed,
                "pose": [pose.x_m, pose.y_m, pose.yaw_rad],
                "window_rad": [window.low_rad, window.high_rad],
                "direction": args.direction,
                "flag_names": {int(f): f.name.lower() for f in SampleFlag},
                "samples": samples,
                "vehicle_pose_at_reference": [x_ref, y_ref, yaw_ref],
                "feature_conventions": FEATURE_CONVENTIONS,
                "features": [feature_to_dict(f, to_world) for f in found],
            },
        )
    if args.plot is not None:
        from cli import plots

        path = Path(args.plot)
        path.parent.mkdir(parents=True, exist_ok=True)
        plots.scan_images(
            scan,
            truth.range_m,
            f"scan of {Path(args.world).name}",
            path,
            top_down=plots.TopDown(filtered, found, to_world),
        )
        print(f"wrote {path}")
    return 0
