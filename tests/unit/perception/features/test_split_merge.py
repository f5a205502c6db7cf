"""Split and merge (:mod:`agent.perception.features.split_merge`): splits judged by each
point's own σ.

The synthetic scans and the tolerances of statistical checks: :mod:`.scans`.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from agent.perception.features import split_merge_kernels
from agent.perception.features.rows import CXX, CYY, ONE, X, Y
from tests.unit.perception.features.scans import (
    L_WALLS,
    UNBIASED,
    Wall,
    features_of,
    simulate_scan,
    stacked,
)


def test_noisy_far_points_do_not_split_a_wall() -> None:
    # At 2.4 m σ ≈ 5 cm per sample: a split test in metres would cut this wall to pieces.
    # Within 2σ of the far limit everywhere, the line would be left out whole as censored
    # (test_censoring); the synthetic scan's gate is on the true range, so nothing is
    # censored here, and the depth of field is opened to test the splitter alone.
    far = Wall((2.7, -2.0), (2.7, 2.0))
    uncut = replace(UNBIASED, depth_of_field_m=(0.0, 1e9))
    for seed in range(100):
        scan = simulate_scan([far], np.random.default_rng(seed))
        assert [f.kind for f in features_of(scan, settings=uncut)] == ["segment"]


def test_precise_near_points_split_at_a_shallow_corner() -> None:
    # Two walls meeting at 32° (just over the corner threshold) 0.8 m away: split every time.
    cx = 0.3 + 0.8
    t = math.radians(16.0)
    vee = [
        Wall((cx - math.sin(t), -math.cos(t)), (cx, 0.0)),
        Wall((cx, 0.0), (cx - math.sin(t), math.cos(t))),
    ]
    for seed in range(50):
        features = features_of(simulate_scan(vee, np.random.default_rng(seed)))
        assert [f.kind for f in features] == ["segment", "corner", "segment"]


# ------------------------------------------------------------------ the compiled arithmetic
def _numpy_best_split(rows: np.ndarray, w: np.ndarray) -> int:
    """Where the numpy formulation splits a piece (prefix sums of weighted moments)."""
    x, y = rows[X] - rows[X, 0], rows[Y] - rows[Y, 0]
    wx, wy = w * x, w * y
    cum = np.cumsum(np.stack([w, wx, wy, wx * x, wy * y, wx * y]), axis=1)
    left = cum[:, 1:-2]

    def lam_min(mm: np.ndarray) -> np.ndarray:
        sw, sx, sy, sxx, syy, sxy = mm
        cxx, cyy, cxy = sxx - sx * sx / sw, syy - sy * sy / sw, sxy - sx * sy / sw
        return np.asarray(0.5 * (cxx + cyy) - np.sqrt(0.25 * (cxx - cyy) ** 2 + cxy * cxy))

    return 2 + int(np.argmin(lam_min(left) + lam_min(cum[:, -1:] - left)))


def _numpy_boundary(rows: np.ndarray, lines: list[tuple[float, float]]) -> int:
    """Where the numpy formulation puts the boundary between two lines (α, ρ)."""
    z2 = []
    for alpha, rho in lines:
        c, s = math.cos(alpha), math.sin(alpha)
        d = np.array([-rho, c, s]) @ rows[ONE : Y + 1]
        var = np.maximum(np.array([c * c, c * s, s * s]) @ rows[CXX : CYY + 1], 1e-12)
        z2.append(d * d / var)
    cost = np.concatenate([[0.0], np.cumsum(z2[0])]) + np.concatenate(
        [np.cumsum(z2[1][::-1])[::-1], [0.0]]
    )
    return int(np.argmin(cost))


def test_split_kernels_are_the_numpy_formulation(rng: np.random.Generator) -> None:
    # The splits are decisions: the kernels must take the numpy formulation's everywhere.
    # (The residuals' products with the lines are BLAS's as numpy's @ takes them.)
    rows = stacked(simulate_scan(L_WALLS, rng)).rows
    m = rows.shape[1]
    for start, stop in ((0, m), (5, m - 7), (m // 2 - 20, m // 2 + 25)):
        w = rng.uniform(0.5, 2.0, stop - start) * 1e4
        k = split_merge_kernels.best_split(rows, start, stop, w)
        assert k == start + _numpy_best_split(rows[:, start:stop], w)
    corner = split_merge_kernels.best_split(rows, 0, m, 1.0 / rows[CXX])
    (a1, rho1), (a2, rho2) = (math.pi, 1.3), (0.4, 1.6)
    for lo, hi in ((corner - 4, corner + 4), (corner - 2, corner + 1), (3, 9)):
        k = split_merge_kernels.boundary(rows, lo, hi, rho1, *_normal(a1), rho2, *_normal(a2))
        assert k == lo + _numpy_boundary(rows[:, lo:hi], [(a1, rho1), (a2, rho2)])


def _normal(alpha: float) -> tuple[float, float]:
    return math.cos(alpha), math.sin(alpha)
