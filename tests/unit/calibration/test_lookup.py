"""The calibration's fused look-up (:mod:`agent.calibration.lookup`): the bilinear formula
written out per table, to the last bit."""

from __future__ import annotations

import numpy as np

from agent.arrays import FloatArray
from agent.calibration.table import ANGLE_TOLERANCE_RAD, Calibration


def _per_table(
    calibration: Calibration, theta: FloatArray, u: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """``1/r`` and its gradient by the textbook formula, one table at a time."""
    tg, ug = calibration.scan_angle_grid_rad, calibration.position_grid
    fi = (theta - tg[0]) / (tg[1] - tg[0])
    fj = (u - ug[0]) / (ug[1] - ug[0])
    slack = ANGLE_TOLERANCE_RAD / (tg[1] - tg[0])
    with np.errstate(invalid="ignore"):
        inside = (fi >= -slack) & (fi <= tg.size - 1 + slack)
        inside &= (fj >= -1e-9) & (fj <= ug.size - 1 + 1e-9)
    fi = np.clip(np.nan_to_num(fi), 0.0, tg.size - 1)
    fj = np.clip(np.nan_to_num(fj), 0.0, ug.size - 1)
    i0 = np.minimum(fi.astype(np.intp), tg.size - 2)
    j0 = np.minimum(fj.astype(np.intp), ug.size - 2)
    a, b = fi - i0, fj - j0
    out = []
    for table in (
        calibration.inverse_range_per_m,
        np.gradient(calibration.inverse_range_per_m, ug, axis=1),
    ):
        value = (
            (1 - a) * (1 - b) * table[i0, j0]
            + (1 - a) * b * table[i0, j0 + 1]
            + a * (1 - b) * table[i0 + 1, j0]
            + a * b * table[i0 + 1, j0 + 1]
        )
        out.append(np.where(inside, value, np.nan))
    return out[0], out[1]


def test_lookup_is_the_bilinear_formula(calibration: Calibration, rng: np.random.Generator) -> None:
    tg, ug = calibration.scan_angle_grid_rad, calibration.position_grid
    edges = [tg[0] - 0.5 * ANGLE_TOLERANCE_RAD, tg[-1] + 0.5 * ANGLE_TOLERANCE_RAD, tg[0] - 2e-3]
    theta = np.concatenate(
        [rng.uniform(tg[0] - 0.01, tg[-1] + 0.01, 4000), tg, edges, [np.nan, np.inf, -np.inf]]
    )
    u = np.concatenate(
        [rng.uniform(-1.05, 1.05, 4000), rng.choice(ug, tg.size), [ug[0], ug[-1], 0.3],
         [0.1, np.nan, 0.2]]
    )  # fmt: skip
    q, dq = calibration.lookup(theta, u)
    q0, dq0 = _per_table(calibration, theta, u)
    np.testing.assert_array_equal(q, q0)  # (NaN where NaN)
    np.testing.assert_array_equal(dq, dq0)
    assert np.isfinite(q).sum() > 3000 and np.isnan(q).sum() > 200  # both cases tested
