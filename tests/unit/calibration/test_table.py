"""The calibration table: file format, look-up, per-sample σ, delay correction."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from agent.calibration.table import CALIBRATION_VERSION, Calibration, delay_corrected
from agent.errors import CalibrationFileError
from agent.kinematics.trajectory import StaticPose
from agent.perception.evaluation import away_from_edges
from agent.sensor.params import SensorParameters
from agent.sensor.samples import RawScan
from agent.sim.simulator import SensorSimulator
from agent.sim.targets import head_centred_pose
from agent.sim.world import World


def test_save_and_load_round_trip(calibration: Calibration, tmp_path: Path) -> None:
    path = tmp_path / "cal.npz"
    calibration.save(path)
    again = Calibration.load(path)
    np.testing.assert_array_equal(again.inverse_range_per_m, calibration.inverse_range_per_m)
    assert again.noise_current_A == calibration.noise_current_A
    assert again.metadata == calibration.metadata


def _rewrite(calibration: Calibration, path: Path, **header_changes: object) -> None:
    import io
    import json

    calibration.save(path)
    with np.load(path) as npz:
        arrays = {k: npz[k] for k in npz.files}
    header = json.loads(bytes(arrays["header"]).decode())
    header.update(header_changes)
    header = {k: v for k, v in header.items() if v is not None}
    arrays["header"] = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    path.write_bytes(buffer.getvalue())


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"version": CALIBRATION_VERSION + 1}, "format version 2 is not supported"),
        ({"format": "something-else"}, "not a lep-range-calibration file"),
        ({"noise_current_A": None}, "missing entry 'noise_current_A'"),
        ({"fd_m2": -1.0}, r"fd_m2 must be from 0.002375 to 0.0095 \(half to twice"),
    ],
)
def test_bad_calibration_files_are_named(
    calibration: Calibration, tmp_path: Path, changes: dict[str, object], match: str
) -> None:
    path = tmp_path / "bad.npz"
    _rewrite(calibration, path, **changes)
    with pytest.raises(CalibrationFileError, match=match) as info:
        Calibration.load(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_unreadable_and_foreign_files(tmp_path: Path) -> None:
    with pytest.raises(CalibrationFileError, match=r"missing\.npz: no such file$"):
        Calibration.load(tmp_path / "missing.npz")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip file at all")
    with pytest.raises(CalibrationFileError, match="not a calibration file"):
        Calibration.load(junk)


def test_lookup_outside_the_table_is_no_reading(calibration: Calibration) -> None:
    r, s = calibration.ranges(
        np.radians([0.0, 25.0, 0.0, 0.0]),
        np.array([0.0, 0.0, 1.5, 0.0]),
        np.array([1e-8, 1e-8, 1e-8, -1e-12]),
    )
    assert np.isfinite(r[0]) and np.isfinite(s[0])
    assert np.isnan(r[1]) and np.isnan(r[2])  # beyond ±20°, off the detector
    assert np.isfinite(r[3]) and np.isnan(s[3])  # a reading without positive signal: σ unknown


def test_sigma_scales_with_inverse_intensity(calibration: Calibration) -> None:
    _, s = calibration.ranges(np.zeros(2), np.zeros(2), np.array([1e-8, 2e-8]))
    assert s[0] == pytest.approx(2 * s[1])


def test_delay_correction_folds_back_at_the_turnaround() -> None:
    rate, delay, fs = math.radians(400), 0.336e-3, 2560.0
    t = (np.arange(4) + 0.5) / fs
    raw = RawScan(t, -0.349 + rate * t, np.zeros(4), np.ones(4), np.ones(4), direction=1)
    times, theta = delay_corrected(raw, delay, rate)
    np.testing.assert_allclose(times, t - delay)
    # The first sample measured the beam 0.14 ms before the turn, on the way in.
    assert theta[0] == pytest.approx(-0.349 + rate * abs(t[0] - delay))
    np.testing.assert_allclose(theta[1:], -0.349 + rate * (t[1:] - delay))


def _random_scene(rng: np.random.Generator) -> World:
    walls, boxes, cylinders = [], [], []
    for _ in range(rng.integers(1, 3)):  # walls at 0.6-2.4 m, up to 60° from square-on
        bearing = rng.uniform(-0.3, 0.3)
        dist = rng.uniform(0.6, 2.4)
        tilt = bearing + rng.uniform(-1.0, 1.0)
        cx, cy = dist * math.cos(bearing), dist * math.sin(bearing)
        dx, dy = -math.sin(tilt), math.cos(tilt)
        walls.append(
            (((cx - 2 * dx, cy - 2 * dy), (cx + 2 * dx, cy + 2 * dy)), float(rng.uniform(0.3, 2.0)))
        )
    for _ in range(rng.integers(0, 3)):
        d, b = rng.uniform(0.6, 2.0), rng.uniform(-0.35, 0.35)
        boxes.append(
            (
                (d * math.cos(b), d * math.sin(b)),
                tuple(rng.uniform(0.1, 0.5, 2)),
                float(rng.uniform(0, math.pi)),
                float(rng.uniform(0.3, 2.0)),
            )
        )
    for _ in range(rng.integers(0, 3)):
        d, b = rng.uniform(0.6, 2.0), rng.uniform(-0.35, 0.35)
        cylinders.append(
            (
                (d * math.cos(b), d * math.sin(b)),
                float(rng.uniform(0.05, 0.3)),
                float(rng.uniform(0.3, 2.0)),
            )
        )
    return World.build(walls=walls, boxes=boxes, cylinders=cylinders)


def test_range_errors_are_consistent_with_predicted_sigma(
    calibration: Calibration, head: SensorParameters
) -> None:
    """Done means: (range − truth)/σ has std in 0.9-1.1 and mean within ±0.1.

    Over random scenes (walls at up to 60° incidence, boxes, cylinders, reflectivities
    0.3-2.0), on visible samples at 0.5-2.5 m whose neighbours within ±3 samples lie on the
    same surface (away from discontinuities). Several thousand samples: the std and mean are
    known to ~0.02, so the bounds fail a σ that is off by 10 % or a bias of 0.1 σ.
    """
    rng = np.random.default_rng(12)
    z_scores = []
    for i in range(60):
        sim = SensorSimulator(_random_scene(rng), head, rng)
        raw, truth = sim.sweep(direction=1 if i % 2 else -1, trajectory=head_centred_pose(head))
        scan = calibration.calibrate_scan(raw)
        ok = away_from_edges(truth, (0.5, 2.5)) & np.isfinite(scan.range_m)
        z_scores.append((scan.range_m[ok] - truth.range_m[ok]) / scan.sigma_m[ok])
    z = np.concatenate(z_scores)
    assert z.size > 3000
    assert 0.9 <= z.std() <= 1.1
    assert abs(z.mean()) <= 0.1


def test_stare_readings_use_the_table(calibration: Calibration, head: SensorParameters) -> None:
    world = World.build(walls=[(((1.3, -1.0), (1.3, 1.0)), 1.0)])
    sim = SensorSimulator(world, head, np.random.default_rng(2))
    raw, _ = sim.stare(0.0, 500, trajectory=StaticPose(-head.mount_offset_m, 0.0, 0.0))
    scan = calibration.calibrate_scan(raw)
    assert np.mean(scan.range_m) == pytest.approx(1.3, abs=3 * np.mean(scan.sigma_m) / 10)
