"""Segmentation along the scan line (:mod:`agent.perception.filtering.segmentation` and
its kernels), with the intensity gate; phantoms and losses over random scenes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.calibration.table import Calibration
from agent.perception.evaluation import away_from_edges
from agent.perception.filtering import (
    FilterSettings,
    SampleFlag,
    gate_and_segment,
    segment_scan,
    segmentation_kernels,
    validation_gates,
)
from agent.perception.filtering.segmentation_kernels import (
    label_runs,
    linear_predictions,
    scan_breaks,
)
from agent.sensor.params import SensorParameters
from agent.sim.simulator import SensorSimulator
from agent.sim.targets import head_centred_pose
from agent.sim.world import World
from tests.unit.perception.filtering.scans import SETTINGS, calibrated_scan, gate_and_segment_scan


def test_linear_predictions_from_either_side() -> None:
    # A quadratic profile with unequal variances: each prediction is the weighted
    # straight-line fit of the four samples on its side, extrapolated to the sample
    # (checked against numpy.polyfit with weights 1/σ); NaN where a side has too few.
    rng = np.random.default_rng(3)
    r = 1.0 + 0.01 * np.arange(12) ** 2
    var = rng.uniform(0.5, 2.0, 12) * 1e-6
    fwd, fvar, bwd, bvar = linear_predictions(r, var, 4)
    for k in range(12):
        for side, pred, pvar in (("before", fwd, fvar), ("after", bwd, bvar)):
            ks = np.arange(k - 4, k) if side == "before" else np.arange(k + 1, k + 5)
            if ks.min() < 0 or ks.max() > 11:
                assert math.isnan(pred[k]) and math.isnan(pvar[k])
                continue
            coef, cov = np.polyfit(ks - k, r[ks], 1, w=1 / np.sqrt(var[ks]), cov="unscaled")
            assert pred[k] == pytest.approx(coef[1], rel=1e-12)
            assert pvar[k] == pytest.approx(cov[1, 1], rel=1e-9)


def test_a_plain_wall_is_one_segment_with_nothing_dropped(
    head: SensorParameters, calibration: Calibration
) -> None:
    wall = World.build(walls=[(((1.4, -1.5), (1.0, 1.5)), 1.0)])
    for seed in range(5):
        scan, _ = calibrated_scan(wall, head, calibration, seed)
        flags, segment = gate_and_segment_scan(scan, calibration)
        assert np.all(flags == SampleFlag.VALID), np.bincount(flags)
        assert set(segment) == {0}


def test_box_before_wall_is_three_surfaces_with_transitions_flagged(
    head: SensorParameters, calibration: Calibration
) -> None:
    world = World.build(
        walls=[(((2.0, -1.5), (2.0, 1.5)), 1.0)], boxes=[((1.2, 0.0), (0.4, 0.4), 0.0, 1.0)]
    )
    for seed in range(5):
        scan, truth = calibrated_scan(world, head, calibration, seed)
        flags, segment = gate_and_segment_scan(scan, calibration)
        assert segment.max() == 2  # wall, box, wall
        # The missing part right of the box (return path blocked) is noise only: dropped.
        hidden = ~truth.visible
        assert np.all(flags[hidden] != SampleFlag.VALID)
        # Nothing kept lies far from its own surface.
        kept = flags == SampleFlag.VALID
        z = np.abs(scan.range_m - truth.range_m)[kept] / scan.sigma_m[kept]
        assert z.max() < 5.0


def test_without_the_intensity_gate_a_small_step_goes_unnoticed(
    head: SensorParameters, calibration: Calibration
) -> None:
    # A 3 cm step between a dark and a bright surface at 2 m: the range change is ~1σ, the
    # intensity change is large. The intensity validation gate breaks the scan there.
    world = World.build(walls=[(((2.0, -1.5), (2.0, 0.0)), 0.4), (((2.03, 0.0), (2.03, 1.5)), 1.6)])
    scan, _ = calibrated_scan(world, head, calibration)
    flags = validation_gates(scan.range_m, scan.intensity_A, calibration.noise_current_A, SETTINGS)
    _, with_gate = segment_scan(scan.range_m, scan.sigma_m, scan.intensity_A, flags, SETTINGS)
    loose = FilterSettings(intensity_ratio_gate=1e6)
    _, without = segment_scan(scan.range_m, scan.sigma_m, scan.intensity_A, flags, loose)

    def boundaries_near_step(segment: np.ndarray) -> int:
        theta = np.degrees(scan.scan_angle_rad)
        kept = segment >= 0
        change = np.flatnonzero(np.diff(segment[kept]) != 0)
        return int(np.sum(np.abs(theta[kept][change]) < 1.5))

    assert boundaries_near_step(with_gate) >= 1
    assert boundaries_near_step(without) == 0


def test_phantoms_and_losses_over_random_scenes(
    head: SensorParameters, calibration: Calibration
) -> None:
    """Valid samples > 5σ from truth ≤ 0.5 %; visible samples away from edges lost ≤ 2 %.

    40 scenes, ~9,000 valid samples: a rate of 0.5 % would show ~45; seen are a handful.
    """
    from tests.unit.calibration.test_table import _random_scene

    rng = np.random.default_rng(3)
    valid = phantoms = visible = lost = 0
    for i in range(40):
        sim = SensorSimulator(_random_scene(rng), head, rng)
        raw, truth = sim.sweep(direction=1 if i % 2 else -1, trajectory=head_centred_pose(head))
        scan = calibration.calibrate_scan(raw)
        flags, _ = gate_and_segment_scan(scan, calibration)
        ok = flags == SampleFlag.VALID
        with np.errstate(invalid="ignore"):
            far = ~(np.abs(scan.range_m - truth.range_m) <= 5 * scan.sigma_m)
        valid += ok.sum()
        phantoms += (ok & far).sum()
        steady = away_from_edges(truth, (0.4, 2.5))
        visible += steady.sum()
        lost += (steady & ~ok).sum()
    assert valid > 5000 and visible > 5000
    assert phantoms / valid <= 0.005
    assert lost / visible <= 0.02


def test_gates_and_segmentation_in_one_call_are_the_two_steps(
    calibration: Calibration, head: SensorParameters
) -> None:
    # gate_and_segment runs the gates and the segmentation in one compiled call: the same
    # flags and segments as the two steps, and those of the numpy formulation around the
    # compiled breaks and runs, for a scan with transitions and dropped samples.
    world = World.build(
        walls=[(((2.0, -1.5), (2.0, 1.5)), 1.0)], boxes=[((1.2, 0.0), (0.4, 0.4), 0.0, 1.0)]
    )
    scan, _ = calibrated_scan(world, head, calibration)
    flags, segment = gate_and_segment_scan(scan, calibration)
    gated = validation_gates(scan.range_m, scan.intensity_A, calibration.noise_current_A, SETTINGS)
    two_steps = segment_scan(scan.range_m, scan.sigma_m, scan.intensity_A, gated, SETTINGS)
    np.testing.assert_array_equal(flags, two_steps[0])
    np.testing.assert_array_equal(segment, two_steps[1])
    idx = np.flatnonzero(gated == SampleFlag.VALID)
    r = scan.range_m[idx]
    slope = SETTINGS.sample_spacing_rad * math.tan(math.radians(SETTINGS.max_incidence_deg))
    breaks = scan_breaks(
        r, scan.sigma_m[idx] ** 2, scan.intensity_A[idx] * r**2, np.diff(idx), SETTINGS.window,
        SETTINGS.gate_chi2, slope, SETTINGS.intensity_ratio_gate, SETTINGS.max_gap,
    )  # fmt: skip
    runs, code = label_runs(r, breaks, SETTINGS.min_run, SampleFlag.MIXED, SampleFlag.ISOLATED)
    expected_flags = gated.copy()
    expected_flags[idx[code != 0]] = code[code != 0]
    np.testing.assert_array_equal(flags, expected_flags)
    np.testing.assert_array_equal(segment[idx], runs)
    assert np.all(segment[gated != SampleFlag.VALID] == -1)
    assert len(set(segment[segment >= 0].tolist())) >= 3 and np.any(code != 0)


def test_one_compiled_signature_for_writable_and_read_only_arrays(
    calibration: Calibration, head: SensorParameters
) -> None:
    # Decoded messages carry read-only arrays, the tests and the perception bench writable
    # ones: the kernels see read-only ones either way, the signatures warm_up loads (another
    # would be compiled, for seconds, at the first scan that brought it).
    world = World.build(walls=[(((2.0, -1.5), (2.0, 1.5)), 1.0)])
    scan, _ = calibrated_scan(world, head, calibration)
    frozen = [np.array(a) for a in (scan.range_m, scan.sigma_m, scan.intensity_A)]
    for a in frozen:
        a.flags.writeable = False
    noise = calibration.noise_current_A
    k = segmentation_kernels
    kernels = (k.gate_flags, k.segment_flags, k.gate_and_segment)

    def run(r: np.ndarray, sigma: np.ndarray, intensity: np.ndarray) -> None:
        gated = validation_gates(r, intensity, noise, SETTINGS)
        segment_scan(r, sigma, intensity, gated, SETTINGS)
        gate_and_segment(r, sigma, intensity, noise, SETTINGS)

    run(*frozen)
    loaded = [list(kernel.signatures) for kernel in kernels]
    run(scan.range_m, scan.sigma_m, scan.intensity_A)
    assert [list(kernel.signatures) for kernel in kernels] == loaded
