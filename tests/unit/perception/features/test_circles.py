"""Weighted circle fits (:mod:`agent.perception.features.circles` and its kernels): the
model's derivatives, and what fixes no circle.

The synthetic scans and the tolerances of statistical checks: :mod:`.scans`.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.perception.features import circle_kernels, fit_circle
from agent.perception.features.circles import Meeting, kasa
from agent.perception.features.rows import BX, BY, CXX, CYY, OX, OY, X, Y
from agent.perception.features.samples import prepare_samples
from tests.unit.perception.features.scans import (
    CYLINDER,
    INTENSITY_ERROR,
    NOISE_CURRENT_A,
    S_CARDBOARD,
    WALL_1P5,
    simulate_scan,
    stacked,
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
    # Without the smoothing correction, whose small dependence on (c, r) the Jacobian
    # leaves out (see circle_model).
    problem, params = circle_kernels.circle_problem(rows, 0, m, 0.0)
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


def _numpy_kasa(rows: np.ndarray) -> tuple[float, float, float]:
    """The Kåsa circle as numpy formulated it (the kernel's reference): the normal equations
    by ``@``, their inverse by cofactors."""
    x, y = rows[X], rows[Y]
    w = 1.0 / np.maximum(rows[CXX] + rows[CYY], 1e-12)
    a = np.stack([x - x[0], y - y[0], np.ones(x.size)])
    aw = a * w
    (p, q, r), (s, t, u), (v, w_, z) = (aw @ a.T).tolist()
    cof = np.array(
        [
            [t * z - u * w_, r * w_ - q * z, q * u - r * t],
            [u * v - s * z, p * z - r * v, r * s - p * u],
            [s * w_ - t * v, q * v - p * w_, p * t - q * s],
        ]
    )
    sol = (cof / (p * cof[0, 0] + s * cof[0, 1] + v * cof[0, 2])) @ (
        aw @ -(a[0] * a[0] + a[1] * a[1])
    )
    cu, cv = -0.5 * sol[0], -0.5 * sol[1]
    return cu + x[0], cv + y[0], math.sqrt(cu * cu + cv * cv - sol[2])


def test_kasa_is_the_numpy_formulation(rng: np.random.Generator) -> None:
    # The kernel's sums are BLAS's, as numpy's @ takes them: equal to the last bit where
    # numpy and numba call one BLAS (as here); 1e-12 allows two builds of it.
    rows = stacked(simulate_scan([CYLINDER], rng)).rows
    m = rows.shape[1]
    for start, stop in ((0, m), (0, m // 2), (m // 3, m)):
        got = kasa(rows, start, stop)
        assert got is not None
        assert got == pytest.approx(_numpy_kasa(rows[:, start:stop]), rel=1e-12, abs=0.0)


def test_a_trial_step_is_a_full_evaluation_without_its_jacobian(
    rng: np.random.Generator,
) -> None:
    # The fit evaluates its trial steps without the Jacobian; their χ² must be the full
    # evaluation's to the last bit (it decides which step is taken).
    rows = stacked(simulate_scan([CYLINDER], rng)).rows
    m = rows.shape[1]
    # Without the smoothing correction, whose small dependence on (c, r) the Jacobian
    # leaves out (see circle_model).
    problem, params = circle_kernels.circle_problem(rows, 0, m, 0.0)
    assert params == 4
    everywhere = np.ones(m, dtype=bool)
    q = (CYLINDER.center[0] + 0.004, CYLINDER.center[1] - 0.003, CYLINDER.radius * 1.03)
    args = (problem, params, *q, 0.1, True, everywhere, True, everywhere, 0.3, 0.5)
    full = circle_kernels.circle_model(*args)
    trial = circle_kernels.circle_model(*args, False)
    for k in (0, 1, 2, 3, 5):
        np.testing.assert_array_equal(trial[k], full[k])
    assert trial[4].size == 0 and (trial[6], trial[7]) == (full[6], full[7])
    chi2, normal, rhs = circle_kernels._normal_equations(full[3], full[4], full[5], params)
    assert circle_kernels._chi2(trial[3], trial[5]) == chi2
    for _ in range(20):  # residuals of every size, some unweighted: the order of the sum shows
        resid = rng.normal(size=200) * 10.0 ** rng.uniform(-3, 3, 200)
        weight = np.where(rng.uniform(size=200) < 0.2, 0.0, rng.uniform(0.1, 10.0, 200))
        ne_chi2 = circle_kernels._normal_equations(resid, rng.normal(size=(4, 200)), weight, 4)[0]
        assert circle_kernels._chi2(resid, weight) == ne_chi2
    # The normal equations written out are the sums in residual order, to the last bit.
    resid, jac, weight = full[3], full[4], full[5]
    ref_normal, ref_rhs = np.zeros((params, params)), np.zeros(params)
    for i in np.flatnonzero(weight):
        for a in range(params):
            wa = weight[i] * jac[a, i]
            ref_rhs[a] += wa * resid[i]
            for b in range(a + 1):
                ref_normal[a, b] += wa * jac[b, i]
    ref_normal = np.tril(ref_normal) + np.tril(ref_normal, -1).T
    np.testing.assert_array_equal(normal, ref_normal)
    np.testing.assert_array_equal(rhs, ref_rhs)
