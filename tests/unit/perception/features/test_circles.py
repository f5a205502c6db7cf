"""Weighted circle fits (:mod:`agent.perception.features.circles` and its kernels): the
model's derivatives, and what fixes no circle.

The synthetic scans and the tolerances of statistical checks: :mod:`.scans`.
"""

from __future__ import annotations

import numpy as np

from agent.perception.features import circle_kernels, fit_circle
from agent.perception.features.circles import Meeting
from agent.perception.features.rows import BX, BY, OX, OY, X, Y
from agent.perception.features.samples import prepare_samples
from tests.unit.perception.features.scans import (
    CYLINDER,
    INTENSITY_ERROR,
    NOISE_CURRENT_A,
    S_CARDBOARD,
    WALL_1P5,
    simulate_scan,
)


def test_circle_model_derivatives_match_finite_differences(rng: np.random.Generator) -> None:
    # The Gauss-Newton steps and the covariance rest on the analytic Jacobian of the range
    # and log-intensity residuals (see circle_kernels.circle_model). The range residuals'
    # Jacobian −(u, 1) holds the normals fixed, which is exact where the points lie on the
    # circle: they are put there (the intensities keep their noise). Central differences
    # with h = 1e-7 agree to 1e-5 of the column's largest entry (rounding). Only beams
    # meeting the circle inside 60° are compared (the others' intensities are not fitted).
    scan = simulate_scan([CYLINDER], rng)
    args = {k: v for k, v in scan.items() if k not in ("truth_obj", "signal_constant_Am2")}
    samples = prepare_samples(
        **args, signal_constant=S_CARDBOARD, baseline_m=0.05, noise_current_A=NOISE_CURRENT_A,
        intensity_model_sigma=INTENSITY_ERROR, neighbour_correlation=0.0,
    )  # fmt: skip
    assert samples is not None
    q = np.array([CYLINDER.center[0] + 0.004, CYLINDER.center[1] - 0.003, CYLINDER.radius * 1.03])
    rows = samples.rows.copy()
    meet = Meeting.of(rows[OX], rows[OY], rows[BX], rows[BY], *q.tolist())
    rows[X] = rows[OX] + meet.t * rows[BX]
    rows[Y] = rows[OY] + meet.t * rows[BY]
    m = rows.shape[1]
    problem, params = circle_kernels.circle_problem(rows, 0, m)
    assert params == 4
    everywhere = np.ones(m, dtype=bool)

    def model(qq: np.ndarray, lam: float, keep: np.ndarray | None = None) -> tuple:
        return circle_kernels.circle_model(
            problem, params, *qq.tolist(), lam, True, everywhere if keep is None else keep,
            keep is None, everywhere, 0.3, 0.5,
        )  # fmt: skip

    here = model(q, 0.1)
    keep, cos_inc, jac = here[0], here[1], here[4]
    inside = np.concatenate([cos_inc > 0.5, cos_inc > 0.5])
    h = 1e-7
    for k in range(4):
        dq = np.zeros(4)
        dq[k] = h
        up = model(q + dq[:3], 0.1 + dq[3], keep)
        down = model(q - dq[:3], 0.1 - dq[3], keep)
        numeric = (up[3] - down[3]) / (2 * h)
        analytic = -jac[k]
        scale = float(np.max(np.abs(analytic[inside])))
        assert np.max(np.abs(numeric - analytic)[inside]) <= 1e-5 * scale, k
    assert inside[:m].sum() >= 20


def test_fit_circle_rejects_collinear_points(rng: np.random.Generator) -> None:
    scan = simulate_scan([WALL_1P5], rng)
    valid = scan["flag"] == 0
    pts = scan["points_xy"][valid]
    exact = np.column_stack([np.full(pts.shape[0], 1.8), pts[:, 1]])
    for p in (exact, pts):
        out = fit_circle(p, scan["covariance"][valid], scan["origin_xy"][valid])
        assert out is None or out[1] > 5.0  # no circle, or one no cylinder could be


def test_fit_circle_refuses_too_few_points() -> None:
    one = np.array([[1.0, 0.0]])
    cov = np.eye(2)[None] * 1e-6
    assert (
        fit_circle(np.repeat(one, 3, axis=0), np.repeat(cov, 3, axis=0), np.zeros((3, 2))) is None
    )
