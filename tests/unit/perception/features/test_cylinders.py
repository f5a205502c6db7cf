"""The cylinder test (:mod:`agent.perception.features.cylinders`): detection, consistency
of the (cx, cy, r) covariance, and what is no cylinder.

The synthetic scans and the tolerances of statistical checks: :mod:`.scans`.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.perception.features import cylinder_kernels
from agent.perception.features.rows import OX, OY, RANGE, REFL, VX, WINT
from agent.perception.features.samples import prepare_samples
from tests.unit.perception.features.scans import (
    BOX_AND_WALL,
    CYLINDER,
    INTENSITY_ERROR,
    L_WALLS,
    NOISE_CURRENT_A,
    S_CARDBOARD,
    SMALL_FAR_CYLINDER,
    WALL_1P5,
    Arc,
    Wall,
    features_of,
    nees,
    oblique_wall,
    of_kind,
    simulate_scan,
    stacked,
    within_3_sigma,
)


def test_cylinder_is_detected_with_no_line_pieces(rng: np.random.Generator) -> None:
    features = features_of(simulate_scan([CYLINDER], rng))
    assert [f.kind for f in features] == ["cylinder"]
    cyl = features[0]
    assert cyl.dof == 3 and cyl.covariance.shape == (3, 3)
    assert cyl.center is not None and cyl.radius == pytest.approx(cyl.params[2])
    assert within_3_sigma(
        cyl.params - np.array([*CYLINDER.center, CYLINDER.radius]), cyl.covariance
    )


def test_cylinder_nees_is_consistent_over_400_scans() -> None:
    # χ² with 3 dof: the mean of 400 has σ = √(6/400) = 0.12; band ±0.37 (3σ).
    truth = np.array([*CYLINDER.center, CYLINDER.radius])
    values = []
    for seed in range(400):
        features = features_of(simulate_scan([CYLINDER], np.random.default_rng(seed)))
        assert [f.kind for f in features] == ["cylinder"]
        values.append(nees(features[0].params - truth, features[0].covariance))
    assert np.mean(values) == pytest.approx(3.0, abs=0.37)


def test_small_far_cylinder_at_the_noise_limit() -> None:
    # r = 0.05 m at 1.8 m, where σ = 16 mm per sample (Table 1): the range noise all but
    # hides the curvature and the intensities carry the detection and the radius. Over 100
    # scans: detected at least half the time (measured 77 %), never reported as line pieces
    # as well, and inside its 3σ ellipsoid (χ²₃ < 14.2) in ≥ 85 % of detections (measured
    # 92 %). At this limit the covariance is optimistic (NEES median 5.4, mean 6.8): the
    # detections are the scans whose noise let a circle beat a line by χ² 16, and the
    # incidence falls fast across 20 samples, so the first-order model is strained. Over
    # the perception bench's scenes the mean NEES is 3.2 for 3 dof.
    truth = np.array([*SMALL_FAR_CYLINDER.center, SMALL_FAR_CYLINDER.radius])
    detected, inside = 0, 0
    for seed in range(100):
        features = features_of(simulate_scan([SMALL_FAR_CYLINDER], np.random.default_rng(seed)))
        cylinders = of_kind(features, "cylinder")
        if cylinders:
            assert [f.kind for f in features] == ["cylinder"]
            detected += 1
            inside += nees(cylinders[0].params - truth, cylinders[0].covariance) < 14.16
    assert detected >= 50
    assert inside >= 0.85 * detected


def test_flat_intensity_is_no_cylinder(rng: np.random.Generator) -> None:
    # The same samples with their intensity flattened: the geometry alone would pass.
    seed = int(rng.integers(2**31))
    scan = simulate_scan([CYLINDER], np.random.default_rng(seed))
    assert [f.kind for f in features_of(scan)] == ["cylinder"]
    flat = simulate_scan([CYLINDER], np.random.default_rng(seed), flat_intensity=True)
    assert np.array_equal(flat["points_xy"], scan["points_xy"], equal_nan=True)
    assert "cylinder" not in [f.kind for f in features_of(flat)]


def test_walls_are_no_cylinders() -> None:
    for seed in range(50):
        for scene in ([WALL_1P5], [oblique_wall()], L_WALLS, BOX_AND_WALL):
            kinds = [f.kind for f in features_of(simulate_scan(scene, np.random.default_rng(seed)))]
            assert "cylinder" not in kinds


def test_concave_arc_is_no_cylinder() -> None:
    # The inside of a 0.3 m-radius arc facing the sensor, given a cylinder's intensity peak
    # (middle twice as bright as the ends) so that only the geometry can tell: its centre
    # lies on the sensor's side (and no circle met by the beams on its near side fits it).
    bowl = Arc((1.6, 0.0), 0.3, concave=True, span_rad=(-0.9, 0.9))
    for seed in range(20):
        scan = simulate_scan([bowl], np.random.default_rng(seed))
        idx = np.flatnonzero(scan["flag"] == 0)
        u = np.linspace(-1.0, 1.0, idx.size)
        scan["intensity_A"][idx] *= np.sqrt(np.clip(1.0 - u * u, 0.05, 1.0))
        kinds = [f.kind for f in features_of(scan)]
        assert "cylinder" not in kinds and "segment" in kinds


def test_one_spike_does_not_break_a_cylinder() -> None:
    # One sample 8σ out along its beam (the filter's isolated-sample gate would usually drop
    # it): the circle's χ² absorbs it; only two samples beyond 5σ refuse a circle.
    for seed in range(20):
        scan = simulate_scan([CYLINDER], np.random.default_rng(seed))
        k = np.flatnonzero(scan["flag"] == 0)[40]
        beam = scan["points_xy"][k] - scan["origin_xy"][k]
        beam /= np.hypot(*beam)
        spike = 8.0 * math.sqrt(beam @ scan["covariance"][k] @ beam)
        scan["points_xy"][k] += spike * beam
        scan["range_m"][k] += spike
        assert [f.kind for f in features_of(scan)] == ["cylinder"]


def test_convexity_kernel_is_the_numpy_formulation(rng: np.random.Generator) -> None:
    rows = stacked(simulate_scan([CYLINDER], rng)).rows
    m = rows.shape[1]
    for cx, cy in ((1.5, 0.0), (1.2, 0.1), (0.5, 0.0), (3.0, -0.4)):
        for start, stop in ((0, m), (3, m // 2)):
            part = rows[:, start:stop]
            beyond = np.hypot(cx - part[OX], cy - part[OY]) > part[RANGE]
            expected = 2 * int(np.count_nonzero(beyond)) > int(beyond.size)
            assert cylinder_kernels.convex(rows, start, stop, cx, cy) == expected


def test_plane_intensity_profile_uses_the_model_range_not_the_noisy_one(
    rng: np.random.Generator,
) -> None:
    # A wall 2 m away, square-on: σ_r = 1.6e-3·r⁴ ≈ 2.6 cm, so the measured range's r²
    # would move each log intensity by 2σ_r/r ≈ 2.6 %, several times its stated σ (0.3 %
    # model error and I_n/I_s). Reduced with the range to the true line, the residuals are
    # the intensities' own: χ² per sample at most 1.5 (the synthetic intensities carry the
    # model error only, so it is below 1: measured 0.21); reduced with the measured range,
    # above 10 (measured 19.6).
    scan = simulate_scan([Wall((2.3, -1.0), (2.3, 1.0))], rng)
    args = {k: v for k, v in scan.items() if k not in ("truth_obj", "signal_constant_Am2")}
    samples = prepare_samples(
        **args, signal_constant=S_CARDBOARD, baseline_m=0.0, noise_current_A=NOISE_CURRENT_A,
        intensity_model_sigma=INTENSITY_ERROR, neighbour_correlation=0.0,
    )  # fmt: skip
    assert samples is not None
    rows = samples.rows
    m = rows.shape[1]
    # The wall x = 2.3 in the scan's frame: α = 0, ρ = 2.3.
    count, _, chi2 = cylinder_kernels.plane_intensity_misfit(rows, 0, m, 0.0, 2.3)
    assert count > 150
    assert chi2 / count < 1.5
    w = rows[WINT]
    use = w > 0
    g = np.log(rows[REFL][use] / np.abs(rows[VX][use]))  # the measured range's reduction
    lam = np.sum(w[use] * g) / np.sum(w[use])
    assert np.mean(w[use] * (g - lam) ** 2) > 10.0


def test_a_far_walking_mover_is_a_cylinder() -> None:
    # A 0.25 m mover walking across at 0.7 m/s, its near surface 2.3 m from the centre of
    # scanning (σ about 5 cm a sample), through the simulator, filtering and features as in
    # the agent's graph: the sweep smears it by up to 7 cm, and the algebraic circle fit's
    # start was concave on such arcs (a cylinder in 25 of these 40 sweeps, otherwise a
    # segment); with the chord's start as the fallback, measured 40 of 40.
    from agent.calibration.table import load_default_calibration
    from agent.kinematics.trajectory import StaticPose
    from agent.perception.filtering import PoseHistory
    from agent.runtime.messages import stamp_ns
    from agent.sensor.params import simulated_head
    from agent.sim.movers import Mover
    from agent.sim.simulator import SensorSimulator
    from agent.sim.world import World
    from agent.stages.calibration_stage import CalibrationStage
    from agent.stages.features_stage import FeaturesStage
    from agent.stages.filtering_stage import FilteringStage

    head, cal = simulated_head(), load_default_calibration()
    mover = Mover(0.25, 0.8, np.array([[2.55, -3.0], [2.55, 3.0]]), 0.7)
    sim = SensorSimulator(World.build(walls=[], movers=[mover]), head, np.random.default_rng(0))
    pose = StaticPose(-head.mount_offset_m, 0.0, 0.0)  # centre of scanning at the origin
    features = FeaturesStage(cal.signal_constant_Am2, cal.noise_current_A)
    found = 0
    for k in range(40):  # while the mover crosses y = ±0.3 m
        raw, _ = sim.sweep(start_time_s=3.0 / 0.7 + (k - 20) * 0.6 / 0.7 / 40, trajectory=pose)
        t0, t1 = float(raw.time_s[0]), float(raw.time_s[-1])
        filtering = FilteringStage(cal.noise_current_A, mount_offset_m=head.mount_offset_m)
        filtering.poses = PoseHistory.sampled(pose, t0 - 0.05, t1 + 0.02)
        scan = filtering.filter(CalibrationStage(cal).calibrated_message(raw, stamp_ns(t1), 0))
        found += any(f.kind == "cylinder" for f in features.extract(scan))
    assert found >= 36
