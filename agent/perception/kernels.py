"""Compiled inner loops of the perception stages: the feature extractor's fits, the filter's
scan-line predictions and the placement of samples.

:mod:`agent.perception.features` stacks one scan's valid samples as the rows of one matrix
(the layout below) and fits lines and circles to spans of its columns. Those fits iterate:
the weighted line fit re-weights until its normal settles, the circle fit takes Gauss-Newton
steps and halves them. Each iteration is a few dozen operations over tens to a few hundred
samples, so written in numpy it is a dozen small-array calls, each costing about a
microsecond whatever its size; a scan's fits then took most of a millisecond in call
overhead alone, and :mod:`agent.perception.filtering` spent a quarter of a millisecond the
same way. Here those loops are compiled with numba and run over the samples directly.
Compiled code is cached on disk beside this module: the first use on a new machine compiles
it (about fifteen seconds, which ``run.py`` does at install), a new process loads it (a
third of a second, see :func:`warm_up`).

Each kernel computes what its docstring says, in the same order of operations as the
formulas that document it in :mod:`agent.perception.features` (the weighted TLS line of
``_wtls``, its covariance, the circle model of ``_circle_fit``) and
:mod:`agent.perception.filtering`; the tests compare them with ``numpy.polyfit``, with
finite differences and with Monte Carlo.

Kernels take the whole stacked matrix and a span ``[start, stop)`` of its columns rather
than views, so that every call has one compiled signature (C-contiguous float64 rows).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba
import numpy as np
from numpy.typing import NDArray

from agent.arrays import FloatArray

BoolArray = NDArray[np.bool_]

# Rows of the stacked per-sample matrix (see ``agent.perception.features._Samples``): 1, x, y,
# C_xx, 2·C_xy, C_yy, the beam's origin and unit direction, the variance along the beam,
# range, intensity, reflectivity at normal incidence, the unit vector to the detector's
# viewpoint, and the log intensity's weight.
ROWS = 17
ONE, X, Y, CXX, CXY2, CYY, OX, OY, BX, BY, VARB = range(11)
RANGE, INT, REFL, VX, VY, WINT = range(11, ROWS)

# Smallest variance a point may have along any direction, m² ((1 µm)²): keeps weights finite
# when a covariance is (numerically) singular across the beam.
MIN_VARIANCE_M2 = 1e-12

# A Gauss-Newton step that lowers χ² by less than this ends the circle fit. The steps hold
# the normals fixed; with residuals of a few σ that model is good to a fraction of σ only,
# and near the minimum its steps can creep (halved to 1/1000, lowering χ² by 0.005 each, in
# fits that took 60 evaluations). A fall of 0.01 is a tenth of σ along the step.
CREEP_CHI2 = 0.01

_F = TypeVar("_F", bound=Callable[..., Any])


def _compiled(fn: _F) -> _F:
    """Compile ``fn`` with numba (nopython, cached); IEEE arithmetic, numpy's error model
    (a division by zero gives inf or NaN, as in numpy, rather than raising)."""
    return cast(_F, numba.njit(cache=True, error_model="numpy")(fn))


# ------------------------------------------------------------------------------ weighted line
@_compiled
def _normal_weights(
    alpha: float, cxx: FloatArray, cxy2: FloatArray, cyy: FloatArray, out: FloatArray
) -> None:
    """``out[i] = 1 / max(nᵀ C_i n, MIN_VARIANCE_M2)`` for the normal n = (cos α, sin α)."""
    c, s = math.cos(alpha), math.sin(alpha)
    cc, cs, ss = c * c, c * s, s * s
    for i in range(out.size):
        out[i] = 1.0 / max(cc * cxx[i] + cs * cxy2[i] + ss * cyy[i], MIN_VARIANCE_M2)


@_compiled
def wtls(
    rows: FloatArray, start: int, stop: int, iterations: int
) -> tuple[bool, float, float, float, float, float, float, float, float, FloatArray]:
    """Weighted total least squares line through samples [start, stop) (see ``_wtls``).

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


@_compiled
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
    ``_Wtls.covariance``: first order, weights held fixed, from each point's full 2×2
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


# ---------------------------------------------------------------------------- weighted circle
# Rows of a circle problem (see ``circle_problem``).
_P_OX, _P_OY, _P_BX, _P_BY, _P_LEN, _P_CXX, _P_CXY2, _P_CYY = range(8)
_P_VFLOOR, _P_WINT, _P_LOGR, _P_VX, _P_VY, _P_VB = range(8, 14)
_P_ROWS = 14


@_compiled
def circle_problem(rows: FloatArray, start: int, stop: int) -> tuple[FloatArray, int]:
    """The per-beam constants of the circle model of samples [start, stop), and the number
    of parameters fitted: 4 (cx, cy, r and the log reflectivity λ) when at least four
    samples carry usable intensities (positive weight and reflectivity), else 3.
    """
    m = stop - start
    p = np.empty((_P_ROWS, m))
    usable = 0
    for k in range(m):
        i = start + k
        ox, oy, bx, by = rows[OX, i], rows[OY, i], rows[BX, i], rows[BY, i]
        p[_P_OX, k], p[_P_OY, k], p[_P_BX, k], p[_P_BY, k] = ox, oy, bx, by
        p[_P_LEN, k] = math.hypot(rows[X, i] - ox, rows[Y, i] - oy)
        p[_P_CXX, k], p[_P_CXY2, k], p[_P_CYY, k] = rows[CXX, i], rows[CXY2, i], rows[CYY, i]
        p[_P_VFLOOR, k] = 0.01 * rows[VARB, i]
        refl = rows[REFL, i]
        if rows[WINT, i] > 0.0 and refl > 0.0 and math.isfinite(math.log(refl)):
            p[_P_WINT, k] = rows[WINT, i]
            p[_P_LOGR, k] = math.log(refl)
            usable += 1
        else:
            p[_P_WINT, k] = 0.0
            p[_P_LOGR, k] = 0.0
        vx, vy = rows[VX, i], rows[VY, i]
        p[_P_VX, k], p[_P_VY, k], p[_P_VB, k] = vx, vy, vx * bx + vy * by
    return p, 4 if usable >= 4 else 3


@_compiled
def circle_model(
    p: FloatArray,
    params: int,
    cx: float,
    cy: float,
    r: float,
    lam: float,
    lam_given: bool,
    keep_in: BoolArray,
    select: bool,
    within: BoolArray,
    min_cos: float,
    intensity_min_cos: float,
) -> tuple[
    BoolArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, float, int
]:  # fmt: skip
    """The circle model (cx, cy, r, λ) of a :func:`circle_problem` (see ``_circle_fit``).

    Per beam ``o + t·b``: it meets the circle at ``t = B − h``, ``B = b·(c − o)``,
    ``h = √(B² − |c − o|² + r²)`` (a beam that misses at its closest approach, h = 0); the
    outward normal there is ``u``, cos(incidence) ``= −u·b``. The range residual is the
    point's offset from the circle's tangent there, ``(|o + t b − c| − r) − (L − t)·cos``,
    with variance ``uᵀ C u`` (floored at 1 % of the along-beam variance) and Jacobian
    −(u, 1, 0). The intensity residual is ``log(I r²/(S cos θ)) − log(u·v) − λ`` (v toward
    the detector's viewpoint) with Jacobian −(∂ log(u·v)/∂(c, r), 1), fitted where the beam
    meets the circle within acos(``intensity_min_cos``).

    The range residuals are fitted over ``keep_in``, or when ``select``, over the beams
    meeting the circle within acos(``min_cos``) that are also in ``within``. λ is
    ``lam``, or when not ``lam_given``, the weighted mean of the log reflectivities.

    Returns (keep, cos(incidence), range variances, residuals (2m,: ranges then
    intensities), minus their Jacobian (4, 2m; its first two rows hold u), weights (2m,), λ,
    intensities fitted).
    With 3 parameters the intensity half has zero weight and λ is 0.
    """
    m = p.shape[1]
    keep = np.empty(m, dtype=np.bool_)
    cos_inc = np.empty(m)
    v = np.empty(m)
    resid = np.zeros(2 * m)
    jac = np.zeros((4, 2 * m))
    weight = np.zeros(2 * m)
    g = np.zeros(m)
    total_w = total_wg = 0.0
    intensities = 0
    for i in range(m):
        ox, oy, bx, by = p[_P_OX, i], p[_P_OY, i], p[_P_BX, i], p[_P_BY, i]
        ocx, ocy = cx - ox, cy - oy
        big_b = bx * ocx + by * ocy
        half = math.sqrt(max(big_b * big_b - (ocx * ocx + ocy * ocy) + r * r, 0.0))
        t = big_b - half
        fx, fy = t * bx - ocx, t * by - ocy  # meeting point − centre
        flen = max(math.hypot(fx, fy), 1e-12)
        uxi, uyi = fx / flen, fy / flen
        ci = -(uxi * bx + uyi * by)
        kept = (ci >= min_cos and within[i]) if select else keep_in[i]
        keep[i] = kept
        cos_inc[i] = ci
        vi = uxi * (uxi * p[_P_CXX, i] + uyi * p[_P_CXY2, i]) + uyi * uyi * p[_P_CYY, i]
        vi = max(vi, p[_P_VFLOOR, i])
        v[i] = vi
        jac[0, i], jac[1, i], jac[2, i] = uxi, uyi, 1.0
        resid[i] = (flen - r) - (p[_P_LEN, i] - t) * ci
        weight[i] = 1.0 / vi if kept else 0.0
        if params == 4:
            vx, vy, vb = p[_P_VX, i], p[_P_VY, i], p[_P_VB, i]
            half_i = max(half, 1e-9 * r)
            cos_view = max(uxi * vx + uyi * vy, 1e-9)
            rcv = r * cos_view
            k = m + i
            jac[0, k] = (vb * (bx - (big_b * bx - ocx) / half_i) - vx) / rcv
            jac[1, k] = (vb * (by - (big_b * by - ocy) / half_i) - vy) / rcv
            jac[2, k] = -vb / (half_i * cos_view) - 1.0 / r
            jac[3, k] = 1.0
            w_int = p[_P_WINT, i] if (kept and ci >= intensity_min_cos) else 0.0
            g[i] = p[_P_LOGR, i] - math.log(cos_view)
            weight[k] = w_int
            if w_int != 0.0:
                intensities += 1
                total_w += w_int
                total_wg += w_int * g[i]
    if params == 4:
        if not lam_given:
            lam = total_wg / total_w if total_w > 0.0 else 0.0
        for i in range(m):
            resid[m + i] = g[i] - lam
    else:
        lam = 0.0
    return keep, cos_inc, v, resid, jac, weight, lam, intensities


@_compiled
def _normal_equations(
    resid: FloatArray, jac: FloatArray, weight: FloatArray, params: int
) -> tuple[float, FloatArray, FloatArray]:
    """χ² = Σ w e², the normal matrix Σ w a aᵀ and Σ w a e over the weighted residuals."""
    normal = np.zeros((params, params))
    rhs = np.zeros(params)
    chi2 = 0.0
    for i in range(resid.size):
        wi = weight[i]
        if wi == 0.0:
            continue
        e = resid[i]
        chi2 += wi * e * e
        for a in range(params):
            wa = wi * jac[a, i]
            rhs[a] += wa * e
            for b in range(a + 1):
                normal[a, b] += wa * jac[b, i]
    for a in range(params):
        for b in range(a):
            normal[b, a] = normal[a, b]
    return chi2, normal, rhs


@_compiled
def _inverse(a: FloatArray) -> tuple[bool, FloatArray]:
    """Inverse of a small matrix by Gauss-Jordan elimination with partial pivoting (at 3×3
    and 4×4 far cheaper than a LAPACK call); False when singular or not finite."""
    n = a.shape[0]
    work = a.copy()
    inv = np.eye(n)
    for col in range(n):
        pivot = col
        for row in range(col + 1, n):
            if abs(work[row, col]) > abs(work[pivot, col]):
                pivot = row
        if not (work[pivot, col] != 0.0 and math.isfinite(work[pivot, col])):
            return False, inv
        if pivot != col:
            for k in range(n):
                work[col, k], work[pivot, k] = work[pivot, k], work[col, k]
                inv[col, k], inv[pivot, k] = inv[pivot, k], inv[col, k]
        d = work[col, col]
        for k in range(n):
            work[col, k] /= d
            inv[col, k] /= d
        for row in range(n):
            if row != col:
                f = work[row, col]
                if f != 0.0:
                    for k in range(n):
                        work[row, k] -= f * work[col, k]
                        inv[row, k] -= f * inv[col, k]
    for i in range(n):
        for j in range(n):
            if not math.isfinite(inv[i, j]):
                return False, inv
    return True, inv


@_compiled
def circle_fit(
    rows: FloatArray,
    start: int,
    stop: int,
    cx: float,
    cy: float,
    r: float,
    min_cos: float,
    max_radius: float,
    intensity_min_cos: float,
    pair_cov: FloatArray,
    iterations: int,
    select_iterations: int,
    hopeless_reduced_chi2: float,
) -> tuple[bool, FloatArray, FloatArray, float, int, int, BoolArray, float]:
    """Gauss-Newton circle fit to samples [start, stop) from (cx, cy, r) (see
    ``agent.perception.features._circle_fit``, which documents the model, the selection of
    beams, the stopping rules and the covariance).

    Returns (ok, q = (cx, cy, r), 3×3 covariance over q, χ², residuals in χ², parameters
    fitted, samples fitted, second largest range residual over its σ); ok False when the fit
    fails (see ``_circle_fit``).
    """
    p, params = circle_problem(rows, start, stop)
    m = stop - start
    q = np.array([cx, cy, r])
    none = np.zeros(m, dtype=np.bool_)
    everywhere = np.ones(m, dtype=np.bool_)
    failed = (False, q, np.zeros((3, 3)), 0.0, 0, params, none, 0.0)
    keep, cos_inc, v, resid, jac, weight, lam, ints = circle_model(
        p, params, cx, cy, r, 0.0, False, none, True, everywhere, min_cos, intensity_min_cos
    )
    chi2, normal, rhs = _normal_equations(resid, jac, weight, params)
    previous_keep = none
    have_previous = False
    converged = False
    for it in range(iterations):
        kept = 0
        for i in range(m):
            kept += keep[i]
        if kept < 4:
            return failed
        settled = have_previous and np.array_equal(keep, previous_keep)
        ok, cov_full = _inverse(normal)
        if not ok:
            return failed
        step = cov_full @ rhs
        if not np.all(np.isfinite(step)):
            return failed
        dof = max(kept + ints - params, 1)
        if settled and chi2 - float(step @ rhs) > hopeless_reduced_chi2 * dof:
            return failed  # even the linearised model's best circle misfits hopelessly
        small = True
        for a in range(params):
            small = small and step[a] * step[a] <= 0.0025 * cov_full[a, a]
        if settled and small:
            q = q + step[:3]  # converged: the step is under 5 % of every σ
            if params == 4:
                lam = lam + step[3]
            converged = True
            break
        t = 1.0
        found = False
        for _halving in range(12):
            cand = q + t * step[:3]
            if cand[2] > 0.0:
                cand_lam = lam + t * step[3] if params == 4 else 0.0
                trial = circle_model(
                    p, params, cand[0], cand[1], cand[2], cand_lam, True, keep, False,
                    everywhere, min_cos, intensity_min_cos,
                )  # fmt: skip
                t_chi2, t_normal, t_rhs = _normal_equations(trial[3], trial[4], trial[5], params)
                # (The fixed point is χ²'s minimum only to first order: allow rounding.)
                if t_chi2 <= chi2 * (1.0 + 1e-9):
                    found = True
                    break
            t *= 0.5
        if not found:
            break  # χ² cannot fall further: at the minimum, to rounding
        q = cand
        if q[2] > max_radius:
            return failed  # flattening out: a plane, or a circle too large to report
        previous_keep = keep
        have_previous = True
        # The next iteration's selection, from the model at the new q.
        t_cos = trial[1]
        next_keep = t_cos >= min_cos
        if it + 1 >= select_iterations:
            next_keep &= keep
        changed = not np.array_equal(next_keep, keep)
        creeping = settled and not changed and chi2 - t_chi2 < CREEP_CHI2
        if changed:
            keep, cos_inc, v, resid, jac, weight, lam, ints = circle_model(
                p, params, q[0], q[1], q[2], trial[6], True, next_keep, False, everywhere,
                min_cos, intensity_min_cos,
            )  # fmt: skip
            chi2, normal, rhs = _normal_equations(resid, jac, weight, params)
        else:
            keep, cos_inc, v, resid, jac, weight, lam, ints = trial
            chi2, normal, rhs = t_chi2, t_normal, t_rhs
        if creeping:
            break
    if converged:  # q moved by the last step: the model there, dropping beams that now graze
        keep, cos_inc, v, resid, jac, weight, lam, ints = circle_model(
            p, params, q[0], q[1], q[2], lam, True, none, True, keep, min_cos,
            intensity_min_cos,
        )  # fmt: skip
        chi2, normal, rhs = _normal_equations(resid, jac, weight, params)
    if not (math.isfinite(q[0] + q[1] + q[2]) and q[2] > 0.0):
        return failed
    kept = 0
    for i in range(m):
        kept += keep[i]
    if kept < 4:
        return failed
    ok, cov_full = _inverse(normal)
    if not ok:
        return failed
    if pair_cov.size == m - 1:
        # The sandwich N⁻¹ (N + Σ_i c_i (a_i a_{i+1}ᵀ + a_{i+1} a_iᵀ)) N⁻¹ over the range
        # terms' weighted Jacobians a_i = weight × ∂e/∂range × (u, 1, 0).
        extra = np.zeros((params, params))
        any_pair = False
        for i in range(m - 1):
            pc = pair_cov[i]
            if pc == 0.0:
                continue
            any_pair = True
            if not (keep[i] and keep[i + 1]):
                continue
            f = pc * (cos_inc[i] / v[i]) * (cos_inc[i + 1] / v[i + 1])
            for a in range(3):
                for b in range(3):
                    extra[a, b] += f * jac[a, i] * jac[b, i + 1]
        if any_pair:
            cov_full = cov_full + cov_full @ (extra + extra.T) @ cov_full
    largest = second = 0.0  # the two largest range residuals over their σ
    for i in range(m):
        if weight[i] > 0.0:
            z = abs(resid[i]) * math.sqrt(weight[i])
            if z > largest:
                largest, second = z, largest
            elif z > second:
                second = z
    cov = np.ascontiguousarray(cov_full[:3, :3])
    return True, q, cov, chi2, kept + ints, params, keep, second


# ---------------------------------------------------------------------------- line's checks
@_compiled
def along_noise_ratio(
    rows: FloatArray, start: int, stop: int, w: FloatArray, alpha: float
) -> float:
    """The points' noise along the line over their true spread along it (see
    ``agent.perception.features._Line.along_noise_ratio``); ∞ when the noise explains all the
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


@_compiled
def plane_intensity_misfit(
    rows: FloatArray, start: int, stop: int, alpha: float
) -> tuple[int, float, float]:
    """The log intensities of samples [start, stop) about one plane's profile (see
    ``agent.perception.features._Cylinders._plane_intensity_z``): (count, largest |z|, Σ z²) of
    ``z = (log(I r²/(S cos θ)) − log cos(viewing angle) − λ) / σ``, λ their weighted mean,
    over the samples with a known intensity seen from the plane's front or back."""
    c, s = math.cos(alpha), math.sin(alpha)
    count = 0
    sw = swg = 0.0
    for i in range(start, stop):
        cos_view = abs(rows[VX, i] * c + rows[VY, i] * s)
        wi = rows[WINT, i]
        if wi > 0.0 and cos_view > 0.0:
            count += 1
            sw += wi
            swg += wi * math.log(rows[REFL, i] / cos_view)
    if count == 0:
        return 0, 0.0, 0.0
    lam = swg / sw
    max_z = chi2 = 0.0
    for i in range(start, stop):
        cos_view = abs(rows[VX, i] * c + rows[VY, i] * s)
        wi = rows[WINT, i]
        if wi > 0.0 and cos_view > 0.0:
            z = (math.log(rows[REFL, i] / cos_view) - lam) * math.sqrt(wi)
            max_z = max(max_z, abs(z))
            chi2 += z * z
    return count, max_z, chi2


# ------------------------------------------------------------------------------- the samples
@_compiled
def sample_rows(
    points: FloatArray,
    cov4: FloatArray,
    origin: FloatArray,
    theta: FloatArray,
    range_m: FloatArray,
    intensity: FloatArray,
    signal_constant: float,
    baseline_m: float,
    noise_current_A: float,
    intensity_model_sigma: float,
) -> tuple[FloatArray, BoolArray]:
    """The stacked rows (see ``agent.perception.features._Samples``) of m samples, and which of them
    are usable: finite geometry, a beam with a direction and a positive semi-definite
    covariance (to rounding).

    ``points`` and ``origin`` (m, 2), ``cov4`` (m, 4) the covariances flattened, ``theta``
    the scan angles, ``range_m`` (the beam's length where not positive), ``intensity`` the
    signal currents; ``noise_current_A`` NaN when intensities are not to be fitted (their
    weights are then 0).
    """
    m = points.shape[0]
    rows = np.empty((ROWS, m))
    good = np.empty(m, dtype=np.bool_)
    fit_intensity = not math.isnan(noise_current_A)
    model_var = intensity_model_sigma * intensity_model_sigma
    for i in range(m):
        x, y = points[i, 0], points[i, 1]
        cxx, cxy2, cyy = cov4[i, 0], cov4[i, 1] + cov4[i, 2], cov4[i, 3]
        ox, oy = origin[i, 0], origin[i, 1]
        th = theta[i]
        rows[ONE, i], rows[X, i], rows[Y, i] = 1.0, x, y
        rows[CXX, i], rows[CXY2, i], rows[CYY, i] = cxx, cxy2, cyy
        rows[OX, i], rows[OY, i] = ox, oy
        length = math.hypot(x - ox, y - oy)
        bx, by = (x - ox) / length, (y - oy) / length
        rows[BX, i], rows[BY, i] = bx, by
        rows[VARB, i] = bx * (bx * cxx + by * cxy2) + by * by * cyy
        r = range_m[i] if range_m[i] > 0.0 else length  # NaN compares False
        rows[RANGE, i] = r
        inten = intensity[i]
        rows[INT, i] = inten
        cos_t, sin_t = math.cos(th), math.sin(th)
        rows[REFL, i] = inten * r * r / (signal_constant * cos_t) if inten > 0.0 else math.nan
        # The head faces the beam turned back by the scan angle; the detector's viewpoint
        # lies a baseline to its left.
        hx, hy = bx * cos_t + by * sin_t, by * cos_t - bx * sin_t
        vx, vy = ox - baseline_m * hy - x, oy + baseline_m * hx - y
        v_len = math.hypot(vx, vy)
        rows[VX, i], rows[VY, i] = vx / v_len, vy / v_len
        w_int = 0.0
        if fit_intensity and inten > 0.0:
            rel = noise_current_A / inten
            w_int = 1.0 / (rel * rel + model_var)
            if not math.isfinite(w_int):
                w_int = 0.0
        rows[WINT, i] = w_int
        finite = math.isfinite(x + y + cxx + cxy2 + cyy + ox + oy + bx + by + th)
        good[i] = (
            finite
            and length > 0.0
            and cxx > 0.0
            and cyy > 0.0
            and 4.0 * cxx * cyy * (1.0 + 1e-9) >= cxy2 * cxy2
        )
    return rows, good


# ------------------------------------------------------------------------------- filtering
@_compiled
def linear_predictions(
    r: FloatArray, var: FloatArray, window: int
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Weighted straight-line predictions of each sample from its neighbours on either side
    (see ``agent.perception.filtering.segment_scan``).

    Returns ``(forward, forward_var, backward, backward_var)``: sample k predicted from
    samples k-window..k-1 and from k+1..k+window (NaN where there are not enough), each
    the intercept of the fit weighted by ``1/var`` with the index as abscissa, with its
    variance ``S_xx / (S_w S_xx − S_x²)``.
    """
    n = r.size
    fwd = np.full(n, np.nan)
    fvar = np.full(n, np.nan)
    bwd = np.full(n, np.nan)
    bvar = np.full(n, np.nan)
    if n <= window:
        return fwd, fvar, bwd, bvar
    for k in range(n):
        for side in range(2):
            if (side == 0 and k < window) or (side == 1 and k >= n - window):
                continue
            sw = sx = sxx = sy = sxy = 0.0
            for j in range(1, window + 1):
                i, x = (k - j, -float(j)) if side == 0 else (k + j, float(j))
                wi = 1.0 / var[i]
                sw += wi
                sx += wi * x
                sxx += wi * x * x
                sy += wi * r[i]
                sxy += wi * x * r[i]
            det = sw * sxx - sx * sx
            if side == 0:
                fwd[k], fvar[k] = (sxx * sy - sx * sxy) / det, sxx / det
            else:
                bwd[k], bvar[k] = (sxx * sy - sx * sxy) / det, sxx / det
    return fwd, fvar, bwd, bvar


@_compiled
def scan_breaks(
    r: FloatArray,
    var: FloatArray,
    corrected: FloatArray,
    steps: NDArray[np.int64],
    window: int,
    gate_chi2: float,
    slope_per_step: float,
    intensity_ratio_gate: float,
    max_gap: int,
) -> BoolArray:
    """Where the scan breaks between valid samples j and j + 1 (see
    ``agent.perception.filtering.segment_scan``): each disagrees with the prediction from the other
    side, the range changes faster than ``r · slope_per_step`` per scan step (plus 5σ),
    the range-corrected intensity ``corrected`` changes by more than the ratio gate, or
    more than ``max_gap`` samples are missing between them (``steps`` the scan steps
    between neighbours).
    """
    n = r.size
    fwd, fvar, bwd, bvar = linear_predictions(r, var, window)
    breaks = np.zeros(max(n - 1, 0), dtype=np.bool_)
    for j in range(n - 1):
        # A missing prediction (NaN, near the ends) cannot disagree.
        right_bad = (r[j + 1] - fwd[j + 1]) ** 2 / (var[j + 1] + fvar[j + 1]) > gate_chi2
        left_bad = (r[j] - bwd[j]) ** 2 / (var[j] + bvar[j]) > gate_chi2
        limit = min(r[j], r[j + 1]) * slope_per_step * steps[j]
        too_steep = abs(r[j + 1] - r[j]) > limit + 5.0 * math.sqrt(var[j] + var[j + 1])
        ratio = corrected[j + 1] / corrected[j]
        jump = not (ratio < intensity_ratio_gate and ratio > 1.0 / intensity_ratio_gate)
        breaks[j] = (right_bad and left_bad) or too_steep or jump or steps[j] > max_gap + 1
    return breaks


@_compiled
def label_runs(
    r: FloatArray, breaks: BoolArray, min_run: int, mixed: int, isolated: int
) -> tuple[NDArray[np.int32], NDArray[np.uint8]]:
    """Number the runs between ``breaks`` that have at least ``min_run`` samples 0, 1, ...
    (-1 for the others), and give each sample of a shorter run the code ``mixed`` when its
    range lies strictly between the ranges of the samples either side of its run, else
    ``isolated`` (0 for the samples of kept runs)."""
    n = r.size
    segment = np.full(n, -1, dtype=np.int32)
    code = np.zeros(n, dtype=np.uint8)
    label = 0
    start = 0
    for stop in range(1, n + 1):
        if stop < n and not breaks[stop - 1]:
            continue
        if stop - start >= min_run:
            segment[start:stop] = label
            label += 1
        else:
            before = r[start - 1] if start > 0 else math.nan
            after = r[stop] if stop < n else math.nan
            if math.isnan(before):
                lo = hi = after
            elif math.isnan(after):
                lo = hi = before
            else:
                lo, hi = min(before, after), max(before, after)
            for i in range(start, stop):
                code[i] = mixed if lo < r[i] < hi else isolated
        start = stop
    return segment, code


@_compiled
def place_points(
    x: FloatArray,
    y: FloatArray,
    yaw: FloatArray,
    beam_rad: FloatArray,
    range_m: FloatArray,
    sigma_m: FloatArray,
    scan_angle_sigma_rad: float,
    reference: FloatArray,
    mount_offset_m: float,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Samples placed in the vehicle frame at the reference pose (see
    ``agent.perception.filtering.place_samples``).

    Sample i's beam leaves the centre of scanning, ``mount_offset_m`` ahead of the vehicle
    pose (x_i, y_i, yaw_i) at its own time, at ``yaw_i + beam_rad_i`` (pan plus scan angle),
    odometry frame; ``reference`` is the vehicle pose (x, y, yaw) the output is relative
    to. Returns points (n, 2), their covariances (n, 2, 2) (``σ_r²`` along the beam,
    ``(r·σ_θ)²`` across it), the centres of scanning (n, 2) and the beams' headings (n,),
    all in the vehicle frame at the reference pose.
    """
    n = x.size
    points = np.empty((n, 2))
    cov = np.empty((n, 2, 2))
    origin = np.empty((n, 2))
    heading = np.empty(n)
    rx, ry, ryaw = reference[0], reference[1], reference[2]
    c, s = math.cos(ryaw), math.sin(ryaw)
    for i in range(n):
        ox = x[i] + mount_offset_m * math.cos(yaw[i]) - rx
        oy = y[i] + mount_offset_m * math.sin(yaw[i]) - ry
        h_odom = yaw[i] + beam_rad[i]
        px = ox + range_m[i] * math.cos(h_odom)
        py = oy + range_m[i] * math.sin(h_odom)
        origin[i, 0], origin[i, 1] = c * ox + s * oy, -s * ox + c * oy
        points[i, 0], points[i, 1] = c * px + s * py, -s * px + c * py
        h = h_odom - ryaw
        ax, ay = math.cos(h), math.sin(h)
        var_along = sigma_m[i] * sigma_m[i]
        across = range_m[i] * scan_angle_sigma_rad
        var_across = across * across
        cov[i, 0, 0] = var_along * ax * ax + var_across * ay * ay
        cov[i, 0, 1] = cov[i, 1, 0] = (var_along - var_across) * ax * ay
        cov[i, 1, 1] = var_along * ay * ay + var_across * ax * ax
        heading[i] = h
    return points, cov, origin, heading


def warm_up() -> None:
    """Load every kernel (compiling them on the first use on this machine, about 15 s;
    cached on disk after that), so that the first scan does not pay for it."""
    m = 8
    rows = np.zeros((ROWS, m))
    rows[ONE] = 1.0
    rows[X] = np.linspace(1.0, 1.1, m)
    rows[Y] = np.linspace(-0.1, 0.1, m)
    rows[CXX] = rows[CYY] = rows[VARB] = 1e-6
    rows[BX] = 1.0
    rows[VX] = -1.0
    rows[REFL] = rows[WINT] = 1.0
    pair_cov = np.zeros(m - 1)
    _, alpha, _, xm, ym, num, den, _, _, w = wtls(rows, 0, m, 6)
    line_covariance(rows, 0, m, w, alpha, xm, ym, num, den, pair_cov, 0.1, True)
    along_noise_ratio(rows, 0, m, w, alpha)
    plane_intensity_misfit(rows, 0, m, alpha)
    circle_fit(rows, 0, m, 1.3, 0.0, 0.2, 0.3, 1.0, 0.5, pair_cov, 30, 3, 15.0)
    cols = np.zeros((m, 2))
    sample_rows(cols, np.zeros((m, 4)), cols.copy(), np.zeros(m), np.ones(m), np.ones(m),
                1.0, 0.1, 1e-10, 0.02)  # fmt: skip
    r = np.ones(m)
    steps = np.ones(m - 1, dtype=np.int64)
    breaks = scan_breaks(r, r * 1e-6, r, steps, 4, 16.0, 0.1, 1.3, 2)
    label_runs(r, breaks, 3, 4, 5)
    place_points(r, r, r, r, r, r, 1e-4, np.zeros(3), 0.1)
