"""The compiled loops of the weighted line fits (:mod:`agent.perception.features.lines`).

The weighted line fit re-weights until its normal settles, each iteration a few dozen
operations over tens to a few hundred samples: written in numpy, a scan's fits took most of
a millisecond in call overhead alone (see :mod:`agent.compiled`). Its iterations, its
covariance and its checks run compiled here. Each kernel computes what its docstring says,
in the same order of operations as the formulas that document it in
:mod:`agent.perception.features.lines` (the weighted TLS line of ``wtls``, its covariance);
the tests check the fits and their covariances by Monte Carlo.
"""

from __future__ import annotations

import math

import numpy as np

from agent.arrays import FloatArray
from agent.compiled import compiled
from agent.perception.features.rows import (
    BX,
    BY,
    CXX,
    CXY2,
    CYY,
    MIN_VARIANCE_M2,
    VARB,
    X,
    Y,
    example_rows,
)


@compiled
def _normal_weights(
    alpha: float, cxx: FloatArray, cxy2: FloatArray, cyy: FloatArray, out: FloatArray
) -> None:
    """``out[i] = 1 / max(nᵀ C_i n, MIN_VARIANCE_M2)`` for the normal n = (cos α, sin α)."""
    c, s = math.cos(alpha), math.sin(alpha)
    cc, cs, ss = c * c, c * s, s * s
    for i in range(out.size):
        out[i] = 1.0 / max(cc * cxx[i] + cs * cxy2[i] + ss * cyy[i], MIN_VARIANCE_M2)


@compiled
def wtls(
    rows: FloatArray, start: int, stop: int, iterations: int
) -> tuple[bool, float, float, float, float, float, float, float, float, FloatArray]:
    """Weighted total least squares line through samples [start, stop) (see ``lines.wtls``).

    Returns (ok, α, ρ, x̄, ȳ, N, D, max |z|, χ², w): the line ``x cos α + y sin α = ρ``
    (ρ ≥ 0, α in (-π, π]), the weighted centroid, the noise-corrected moments N = −2 S_xy
    and D = S_yy − S_xx, the largest residual over σ along the normal and the sum of their
    squares, and the weights 1/(nᵀ C_i n). ``ok`` is False (and the rest meaningless) for
    fewer than two samples or coincident ones.
    """
    m = stop - start
    w = np.empty(max(m, 0))
    if m < 2:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, w
    x, y = rows[X, start:stop], rows[Y, start:stop]
    cxx, cxy2, cyy = rows[CXX, start:stop], rows[CXY2, start:stop], rows[CYY, start:stop]
    # Start from the normal of the chord between the end points.
    a = math.atan2(x[m - 1] - x[0], y[0] - y[m - 1])
    _normal_weights(a, cxx, cxy2, cyy, w)
    a_prev = math.nan
    xm = ym = num = den = 0.0
    for it in range(iterations):
        sw = sx = sy = sxx = syy = sxy = 0.0
        nxx = nxx2 = nxy = nxy2 = nyy = nyy2 = 0.0
        for i in range(m):
            wi, xi, yi = w[i], x[i], y[i]
            ww = wi * wi
            sw += wi
            sx += wi * xi
            sy += wi * yi
            sxx += wi * xi * xi
            syy += wi * yi * yi
            sxy += wi * xi * yi
            nxx += wi * cxx[i]
            nxx2 += ww * cxx[i]
            nxy += wi * cxy2[i]
            nxy2 += ww * cxy2[i]
            nyy += wi * cyy[i]
            nyy2 += ww * cyy[i]
        xm, ym = sx / sw, sy / sw
        # Central moments less the points' own noise, Σ w C − Σ w² C / Σ w.
        mxx = sxx - sx * xm - (nxx - nxx2 / sw)
        myy = syy - sy * ym - (nyy - nyy2 / sw)
        mxy = sxy - sx * ym - 0.5 * (nxy - nxy2 / sw)
        num, den = -2.0 * mxy, myy - mxx
        a = 0.5 * math.atan2(num, den)
        # Converged when the normal moves by < 1 % of σ_α ≈ 1/√(S_xx+S_yy).
        tol = 0.01 / math.sqrt(max(mxx + myy, 1e-300))
        if (not math.isnan(a_prev) and abs(math.sin(a - a_prev)) < tol) or it == iterations - 1:
            break  # keep these weights with the moments they gave
        a_prev = a
        _normal_weights(a, cxx, cxy2, cyy, w)
    if not (num * num + den * den > 0.0 and math.isfinite(num + den)):
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, w
    c, s = math.cos(a), math.sin(a)
    rho = xm * c + ym * s
    if rho < 0.0:
        rho, a, c, s = -rho, a + math.pi, -c, -s
    if a > math.pi:
        a -= 2.0 * math.pi
    max_z = chi2 = 0.0
    for i in range(m):
        zi = (x[i] * c + y[i] * s - rho) * math.sqrt(w[i])
        max_z = max(max_z, abs(zi))
        chi2 += zi * zi
    return True, a, rho, xm, ym, num, den, max_z, chi2, w


@compiled
def line_covariance(
    rows: FloatArray,
    start: int,
    stop: int,
    w: FloatArray,
    alpha: float,
    xm: float,
    ym: float,
    num: float,
    den: float,
    pair_cov: FloatArray,
    common_fraction: float,
    with_beam: bool,
) -> tuple[float, float, float]:
    """(σ_α², σ_αρ, σ_ρ²) of a weighted line through samples [start, stop) (see
    ``lines.Wtls.covariance``: first order, weights held fixed, from each point's full 2×2
    covariance; with ``with_beam``, plus the neighbouring samples' correlated range errors
    ``pair_cov`` (count − 1,) and the common range error ``common_fraction`` of each σ).
    """
    m = stop - start
    x, y = rows[X, start:stop], rows[Y, start:stop]
    cxx, cxy2, cyy = rows[CXX, start:stop], rows[CXY2, start:stop], rows[CYY, start:stop]
    bxs, bys, varb = rows[BX, start:stop], rows[BY, start:stop], rows[VARB, start:stop]
    norm2 = num * num + den * den
    c, s = math.cos(alpha), math.sin(alpha)
    lever = ym * c - xm * s
    total = 0.0
    for i in range(m):
        total += w[i]
    v_aa = v_rr = v_ar = 0.0
    big_a = big_r = 0.0
    ga_prev = gr_prev = 0.0
    pairs = with_beam and pair_cov.size == m - 1
    for i in range(m):
        wdx = w[i] * (x[i] - xm)
        wdy = w[i] * (y[i] - ym)
        ax = (num * wdx - den * wdy) / norm2  # ∂α/∂x_i
        ay = (den * wdx + num * wdy) / -norm2
        wn = w[i] / total
        bx = c * wn + lever * ax  # ∂ρ/∂x_i
        by = s * wn + lever * ay
        v_aa += ax * (ax * cxx[i] + ay * cxy2[i]) + ay * ay * cyy[i]
        v_rr += bx * (bx * cxx[i] + by * cxy2[i]) + by * by * cyy[i]
        v_ar += ax * bx * cxx[i] + ay * by * cyy[i] + 0.5 * (ax * by + ay * bx) * cxy2[i]
        if with_beam:
            ga = ax * bxs[i] + ay * bys[i]  # ∂α/∂range_i
            gr = bx * bxs[i] + by * bys[i]  # ∂ρ/∂range_i
            if pairs and i > 0:
                pc = pair_cov[i - 1]
                v_aa += 2.0 * pc * ga_prev * ga
                v_rr += 2.0 * pc * gr_prev * gr
                v_ar += pc * (ga_prev * gr + gr_prev * ga)
            sigma = math.sqrt(varb[i])
            big_a += ga * sigma
            big_r += gr * sigma
            ga_prev, gr_prev = ga, gr
    if with_beam and common_fraction > 0.0:
        big_a *= common_fraction
        big_r *= common_fraction
        v_aa += big_a * big_a
        v_rr += big_r * big_r
        v_ar += big_a * big_r
    return v_aa, v_ar, v_rr


@compiled
def along_noise_ratio(
    rows: FloatArray, start: int, stop: int, w: FloatArray, alpha: float
) -> float:
    """The points' noise along the line over their true spread along it (see
    ``agent.perception.features.lines.Line.along_noise_ratio``); ∞ when the noise explains all the
    spread."""
    m = stop - start
    c, s = math.cos(alpha), math.sin(alpha)
    tx, ty = -s, c  # along the line
    total = sw_t = noise = noise2 = 0.0
    for k in range(m):
        i = start + k
        wi = w[k]
        along = rows[Y, i] * c - rows[X, i] * s
        var_t = max(tx * tx * rows[CXX, i] + tx * ty * rows[CXY2, i] + ty * ty * rows[CYY, i],
                    MIN_VARIANCE_M2)  # fmt: skip
        total += wi
        sw_t += wi * along
        noise += wi * var_t
        noise2 += wi * wi * var_t
    mean_t = sw_t / total
    spread = 0.0
    for k in range(m):
        i = start + k
        d = rows[Y, i] * c - rows[X, i] * s - mean_t
        spread += w[k] * d * d
    noise -= noise2 / total
    geometric = spread - noise
    return noise / geometric if geometric > 0.0 else math.inf


def warm_up() -> None:
    """Load the line kernels (compiling them on the first use on this machine)."""
    rows = example_rows()
    m = rows.shape[1]
    _, alpha, _, xm, ym, num, den, _, _, w = wtls(rows, 0, m, 6)
    line_covariance(rows, 0, m, w, alpha, xm, ym, num, den, np.zeros(m - 1), 0.1, True)
    along_noise_ratio(rows, 0, m, w, alpha)
