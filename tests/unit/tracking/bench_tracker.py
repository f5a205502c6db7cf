"""Micro-benchmark of :meth:`agent.tracking.tracker.Tracker.update` (not a test).

A vehicle drives a 2 m circle at 0.5 m/s among 10 right-angled corners (20 walls) and 10
pillars (and 10 pillars nearer), the head sweeping ±80°, with 8 false features a scan on
average (Poisson): about 60 tracks (tentative ones included), about 10 features a scan
(``--clutter 2``: about 40 tracks, 4 features). Prints p50/p99 of the update's time
(``perf_counter_ns``), the tracks and features per scan. The same scans go through a new
tracker ``--repeat`` times and each scan counts with its least time: on a shared two-core
machine one run's p99 moves by a third from run to run with the machine's other work.

Run: ``.venv/bin/python -m tests.unit.tracking.bench_tracker [--scans N] [--seed S]
[--clutter C] [--repeat R]``.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from agent import tracking
from agent.tracking.poses import PoseSample
from agent.tracking.tracker import KIND_CORNER, KIND_CYLINDER, FeatureBatch, Tracker
from tests.unit.tracking.scenes import Odometry, Scene, cast, corner_walls, features


def dense_scene(objects: int = 20) -> Scene:
    """Corners (two 0.4 m walls each) and 0.1 m pillars alternating on a 3.3 m ring, and
    pillars on a 0.9 m ring inside the vehicle's 2 m circle."""
    walls, corners, pillars = [], [], []
    for i in range(objects):
        b = 2 * math.pi * i / objects
        if i % 2 == 0:
            apex = (3.4 * math.cos(b), 3.4 * math.sin(b))
            walls.append(corner_walls(apex, b + math.pi, arm_m=0.4))
            corners.append(apex)
        else:
            pillars.append([3.2 * math.cos(b), 3.2 * math.sin(b), 0.1])
    for i in range(objects // 2):
        b = 2 * math.pi * (i + 0.5) / (objects // 2)
        pillars.append([0.9 * math.cos(b), 0.9 * math.sin(b), 0.08])
    return Scene(np.concatenate(walls), np.array(corners), np.array(pillars))


def with_clutter(
    batch: FeatureBatch, rng: np.random.Generator, mean: float, pan: float
) -> FeatureBatch:
    """``batch`` plus a Poisson number of false point features (corners or cylinders)
    uniform over the ±20° window (pointing at ``pan``) at 0.5-2.4 m from the sensor."""
    n = int(rng.poisson(mean))
    if n == 0:
        return batch
    r = rng.uniform(0.5, 2.4, n)
    b = rng.uniform(-0.35, 0.35, n) + pan
    kind = rng.choice(np.array([KIND_CORNER, KIND_CYLINDER], dtype=np.uint8), n)
    params = np.stack([0.3 + r * np.cos(b), r * np.sin(b), np.full(n, 0.1)], axis=1)
    cov = np.tile(np.diag([1e-4, 1e-4, 2.5e-5]), (n, 1, 1))
    cov[kind == KIND_CORNER, 2, :] = np.nan
    cov[kind == KIND_CORNER, :, 2] = np.nan
    params[kind == KIND_CORNER, 2] = np.nan
    return FeatureBatch(
        kind=np.concatenate([batch.kind, kind]),
        params=np.concatenate([batch.params, params]),
        covariance=np.concatenate([batch.covariance, cov]),
        endpoints=np.concatenate([batch.endpoints, np.full((n, 2, 2), np.nan)]),
        reflectivity=np.concatenate([batch.reflectivity, np.ones(n)]),
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scans", type=int, default=600)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--clutter", type=float, default=8.0, help="false features per scan")
    ap.add_argument(
        "--repeat", type=int, default=5,
        help="run the same scans through a new tracker this many times; the figures per scan "
        "are the least of its times (what the scan costs, without the machine's other work)",
    )  # fmt: skip
    ap.add_argument(
        "--baseline", action="store_true",
        help="also time Stone Soup's tracker (cli.baseline_stonesoup, the extra 'baseline') on "
        "the same point features, keeping its tracks as long as the agent's coast (30 s)",
    )  # fmt: skip
    args = ap.parse_args(argv)
    tracking.warm_up()  # load the compiled kernels before timing
    rng = np.random.default_rng(args.seed)
    scene = dense_scene()
    odo = Odometry(rng)
    inputs = []
    for k in range(args.scans):
        t = 0.1 * k
        ang = 0.5 * t / 2.0
        true = np.array([2.0 * math.cos(ang), 2.0 * math.sin(ang), ang + math.pi / 2])
        odo.step(true)
        pan = math.radians(80) * math.sin(2 * math.pi * t / 3.0)
        scan, hits = cast(true, scene, t, pan, (-math.radians(20), math.radians(20)))
        batch, _ = features(true, scene, t, scan, hits, rng)
        inputs.append(
            (round(t * 1e9), odo.sample(), with_clutter(batch, rng, args.clutter, pan), scan)
        )
    times = np.zeros((args.repeat, args.scans))
    for r in range(args.repeat):
        tracker = Tracker()
        n_tracks = []
        for k, (stamp, pose, batch, scan) in enumerate(inputs):
            t0 = time.perf_counter_ns()
            out = tracker.update(stamp, pose, batch, scan)
            times[r, k] = time.perf_counter_ns() - t0
            n_tracks.append(len(out))
    us = times[:, 50:] / 1e3  # after the tracks have formed
    least = us.min(axis=0)
    n_feats = [b.kind.size for _, _, b, _ in inputs]
    one_run = np.percentile(us, 99, axis=1)
    print(
        f"Tracker.update: p50 {np.percentile(least, 50):.0f} us, "
        f"p99 {np.percentile(least, 99):.0f} us (each scan's least of {args.repeat} runs; "
        f"one run's p99 {one_run.min():.0f}-{one_run.max():.0f} us); "
        f"tracks mean {np.mean(n_tracks[50:]):.1f} (max {max(n_tracks)}), "
        f"features per scan mean {np.mean(n_feats):.1f} (max {max(n_feats)}); "
        f"{tracker.counters.as_dict()}"
    )
    if args.baseline:
        _time_baseline(inputs, args.repeat)
    return 0


def _time_baseline(inputs: list[tuple[int, PoseSample, FeatureBatch, object]], repeat: int) -> None:
    """Stone Soup's global nearest neighbour tracker on the same scans' corners and cylinders
    (in ``odom``). Its deleter keeps a track 300 scans without an update (the agent's tracker
    coasts a static track unseen up to 30 s), so that it holds about as many tracks as the
    agent's; with the benchmark's 10 it drops whatever the head turns away from."""
    from cli.baseline_stonesoup import StoneSoupBaseline, detections_in_odom

    repeat = max(1, min(repeat, 2))  # a run takes tens of seconds
    times = np.zeros((repeat, len(inputs)))
    held: list[int] = []
    for r in range(repeat):
        baseline = StoneSoupBaseline(delete_steps=300)
        for k, (stamp, pose, batch, _) in enumerate(inputs):
            kind, xy, cov = detections_in_odom(
                batch.kind, batch.params, batch.covariance, pose.pose
            )
            t0 = time.perf_counter_ns()
            ids, _, _, _ = baseline.step(stamp / 1e9, kind, xy, cov)
            times[r, k] = time.perf_counter_ns() - t0
            if r == 0:
                held.append(int(ids.size))
    ms = times[:, 50:].min(axis=0) / 1e6
    print(
        f"Stone Soup GNN: p50 {np.percentile(ms, 50):.1f} ms, p99 {np.percentile(ms, 99):.1f} ms "
        f"(each scan's least of {repeat} runs); confirmed tracks mean {np.mean(held[50:]):.1f} "
        f"(max {max(held)})"
    )


if __name__ == "__main__":
    raise SystemExit(main())
