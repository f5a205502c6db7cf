"""``sensor-agent bench perception``: filtering and features scored against the simulation's
truth, over the scene classes of :mod:`agent.sim.perception_scenes`.

Scene ``i`` is of class ``scene_class(i)``: every other one the general mix (``random``),
the rest bends, grazing walls and fences in turn. The general scenes take their randomness
(world, noise, motion) from ``default_rng(seed)`` alone, in the order the benchmark drew
them before the targeted classes joined it, so the ``random`` class of N scenes is the
first N/2 scenes of the earlier benchmark, scan for scan; the targeted classes draw from
``default_rng([seed, 1])``. In each class every third scene is scanned while driving and
turning, and the sweep direction alternates.

The scans go through the calibration, filtering and features stages themselves; the
baseline is the same features stage fed the same points with one fixed noise for all of
them. Scoring: :mod:`agent.perception.evaluation`. The time per scan is the filtering and
features stages' own, measured around their calls (``per_scan_ms`` their mean,
``features_ms`` the features stage's p50 and p99, ``filtering_features_ms`` both's).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from agent.calibration.table import load_default_calibration
from agent.runtime.messages import stamp_ns
from agent.sensor.params import simulated_head
from agent.sim.simulator import SensorSimulator
from cli.output import write_json

FIXED_NOISE_M = 0.01  # the baseline's one σ for every point, as line extractors assume
MOVING_EVERY = 3  # in each class, every third scene is scanned while driving and turning


def perception_figures(scenes: int, seed: int) -> dict[str, Any]:
    """Filtering and features over the benchmark's scenes, scored against the truth (see the
    module docstring). Every figure of :meth:`Tally.summary` for all scenes, per class
    (``by_class``) and for the baseline."""
    from agent.kinematics.trajectory import ConstantTwist, Trajectory
    from agent.perception import warm_up
    from agent.perception.evaluation import Tally, paired_accuracy, score_scan
    from agent.perception.filtering import PoseHistory
    from agent.sim.perception_scenes import BENCH_CYCLE, SCENES, scene_class
    from agent.sim.targets import head_centred_pose
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
    warm_up()  # load the compiled loops first: a one-off cost, not a scan's
    streams = {"random": np.random.default_rng(seed), "targeted": np.random.default_rng([seed, 1])}
    classes = list(dict.fromkeys(BENCH_CYCLE))
    weighted, baseline = Tally(), Tally()
    by_class = {name: Tally() for name in classes}
    drawn = dict.fromkeys(classes, 0)
    features_s: list[float] = []
    both_s: list[float] = []
    for i in range(scenes):
        kind = scene_class(i)
        j = drawn[kind]  # this class's own scene count: motion and direction follow it
        drawn[kind] += 1
        rng = streams["random" if kind == "random" else "targeted"]
        world = SCENES[kind](rng)
        trajectory: Trajectory = head_centred_pose(head)
        if j % MOVING_EVERY == MOVING_EVERY - 1:
            trajectory = ConstantTwist(
                -head.mount_offset_m,
                0.0,
                0.0,
                float(rng.uniform(0.2, 0.5)),
                float(rng.uniform(-1, 1)),
            )
        sim = SensorSimulator(world, head, rng)
        raw, truth = sim.sweep(direction=1 if j % 2 else -1, trajectory=trajectory)
        scan = calibrate.calibrated_message(raw, stamp_ns(float(raw.time_s[-1])), i)
        filtering.poses = PoseHistory.sampled(
            trajectory, scan.time_s[0] - 0.05, scan.time_s[-1] + 0.02
        )
        started = time.perf_counter()
        filtered = filtering.filter(scan)
        middle = time.perf_counter()
        found = features.extract(filtered)
        ended = time.perf_counter()
        features_s.append(ended - middle)
        both_s.append(ended - started)
        fixed = np.broadcast_to(np.eye(2) * FIXED_NOISE_M**2, filtered.covariance.shape).copy()
        plain = plain_features.extract(replace(filtered, covariance=fixed))
        x, y, yaw = (float(v[0]) for v in trajectory.poses_at(np.array([scan.time_s[-1]])))
        for tally, found_here in (
            (weighted, found),
            (by_class[kind], found),
            (baseline, plain),
        ):
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
    figures["per_scan_ms"] = 1e3 * float(np.mean(both_s)) if both_s else None
    figures["features_ms"] = _percentiles(features_s)
    figures["filtering_features_ms"] = _percentiles(both_s)
    figures["paired_with_baseline"] = paired_accuracy(weighted, baseline)
    figures["seed"] = seed
    figures["scenes_by_class"] = drawn
    figures["by_class"] = {name: t.summary() for name, t in by_class.items()}
    figures["baseline"] = baseline.summary()
    figures["baseline"]["description"] = (
        f"the same filter and extractor with equal weights, a fixed {FIXED_NOISE_M} m noise "
        "and no intensities in the fits"
    )
    return figures


def _percentiles(seconds: list[float]) -> dict[str, float | None]:
    if not seconds:
        return {"p50": None, "p99": None}
    ms = 1e3 * np.asarray(seconds)
    return {"p50": float(np.percentile(ms, 50)), "p99": float(np.percentile(ms, 99))}


def _show(value: Any, fmt: str) -> str:
    return "n/a" if value is None else format(value, fmt)


def perception_command(args: argparse.Namespace) -> int:
    """``sensor-agent bench perception``."""
    if args.scenes < 1:
        print("sensor-agent: --scenes must be at least 1", file=sys.stderr)
        return 2
    f = perception_figures(args.scenes, args.seed)
    b = f["baseline"]
    print(
        f"perception over {f['scans']} scenes ({f['true_segments']} true segments, "
        f"{f['true_cylinders']} true cylinders), seed {args.seed}; scenes by class "
        + ", ".join(f"{k} {v}" for k, v in f["scenes_by_class"].items())
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
    classes = list(f["by_class"])
    print(f"  {'':30s} {'weighted':>10s} {'baseline':>10s}" + "".join(f"{c:>9s}" for c in classes))

    def line(label: str, get: Any, fmt: str) -> None:
        cells = [get(f), get(b)] + [get(f["by_class"][c]) for c in classes]
        text = [_show(v, fmt) for v in cells]
        print(
            f"  {label:30s} {text[0]:>10s} {text[1]:>10s}" + "".join(f"{t:>9s}" for t in text[2:])
        )

    for label, key, fmt in rows:
        line(label, lambda d, key=key: d[key], fmt)
    for kind in ("segment", "cylinder"):
        for tail, name in (("above_95", "above χ² 95 %"), ("below_5", "below χ² 5 %")):
            line(f"{kind} NEES {name}", lambda d, k=kind, t=tail: d["nees_tails"][k][t], ".1%")
    line("segments across a bend", lambda d: d["bend"]["bridging_rate"], ".1%")
    line("  and uncovered", lambda d: d["bend"]["bridging_uncovered_rate"], ".1%")
    line("  (vertices seen)", lambda d: d["bend"]["vertices_seen"], "d")
    line("grazing segments", lambda d: d["grazing"]["segments"], "d")
    line("  NEES mean", lambda d: d["grazing"]["nees_mean"], ".2f")
    line("  NEES above χ² 95 %", lambda d: d["grazing"]["nees_tails"]["above_95"], ".1%")
    line("  > 5° and uncovered", lambda d: d["grazing"]["wrong_uncovered_rate"], ".1%")
    line("cylinders wrong (r or two)", lambda d: d["cylinder_errors"]["wrong_rate"], ".1%")
    line("  and uncovered", lambda d: d["cylinder_errors"]["wrong_uncovered_rate"], ".1%")
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
    ff, both = f["features_ms"], f["filtering_features_ms"]
    print(
        f"  per scan (one process): filtering + features mean {f['per_scan_ms']:.3f} ms, "
        f"p50 {both['p50']:.3f}, p99 {both['p99']:.3f}; features p50 {ff['p50']:.3f}, "
        f"p99 {ff['p99']:.3f} ms"
    )
    if args.json is not None:
        write_json(Path(args.json), f)
    return 0
