"""The compiled loops of the weighted circle fit (:mod:`agent.perception.features.circles`).

The circle fit takes Gauss-Newton steps and halves them, each step a few dozen operations
over tens to a few hundred samples: written in numpy, a scan's fits took most of a
millisecond in call overhead alone (see :mod:`agent.compiled`). The steps, the model they
evaluate and the covariance run compiled here. Each kernel computes what its docstring
says, in the same order of operations as the formulas that document it in
:mod:`agent.perception.features.circles` (the circle model of ``circle_fit``); the tests
compare the model's derivatives with finite differences.
"""

from __future__ import annotations

import math

import numpy as np

from agent.arrays import BoolArray, FloatArray
from agent.compiled import compiled
from agent.perception.features.rows import (
    BX,
    BY,
    CXX,
    CXY2,
    CYY,
    MIN_VARIANCE_M2,
    OX,
    OY,
    RANGE,
    REFL,
    VARB,
    VX,
    VY,
    WINT,
    X,
    Y,
    example_rows,
)

# A Gauss-Newton step that lowers χ² by less than this ends the circle fit. The steps hold
# the normals fixed; with residuals of a few σ that model is good to a fraction of σ only,
# and near the minimum its steps can creep (halved to 1/1000, lowering χ² by 0.005 each, in
# fits that took 60 evaluations). A fall of 0.01 is a tenth of σ along the step.
CREEP_CHI2 = 0.01

# Rows of a circle problem (see ``circle_problem``).
_P_OX, _P_OY, _P_BX, _P_BY, _P_LEN, _P_CXX, _P_CXY2, _P_CYY = range(8)
_P_VFLOOR, _P_WINT, _P_LOGR, _P_VX, _P_VY, _P_VB, _P_BLUR2 = range(8, 15)
_P_ROWS = 15


@compiled
def _inverse3(m: FloatArray) -> tuple[bool, FloatArray]:
    """Inverse of a 3×3 matrix by cofactors; False when singular or not finite."""
    a, b, c = m[0, 0], m[0, 1], m[0, 2]
    d, e, f = m[1, 0], m[1, 1], m[1, 2]
    g, h, i = m[2, 0], m[2, 1], m[2, 2]
    c00, c01, c02 = e * i - f * h, c * h - b * i, b * f - c * e
    det = a * c00 + d * c01 + g * c02
    out = np.empty((3, 3))
    if not (det != 0.0 and math.isfinite(det)):
        return False, out
    out[0, 0], out[0, 1], out[0, 2] = c00, c01, c02
    out[1, 0], out[1, 1], out[1, 2] = f * g - d * i, a * i - c * g, c * d - a * f
    out[2, 0], out[2, 1], out[2, 2] = d * h - e * g, b * g - a * h, a * e - b * d
    for row in range(3):
        for col in range(3):
            out[row, col] /= det
    return True, out


@compiled
def kasa(rows: FloatArray, start: int, stop: int) -> tuple[bool, float, float, float]:
    """Weighted algebraic (Kåsa) circle through samples [start, stop): (ok, cx, cy, r)
    (see ``circles.kasa``).

    The normal equations' sums are BLAS's matrix products, as numpy's ``@`` takes them
    (numba calls the same routines), so the start of the circle fit, and the fit from it,
    are those of the numpy formulation to the last bit.
    """
    m = stop - start
    a = np.empty((3, m))
    aw = np.empty((3, m))
    b = np.empty(m)
    x0, y0 = rows[X, start], rows[Y, start]  # a local origin keeps the equations conditioned
    for k in range(m):
        i = start + k
        var = rows[CXX, i] + rows[CYY, i]
        if var < MIN_VARIANCE_M2:  # (np.maximum's rule: NaN stays NaN)
            var = MIN_VARIANCE_M2
        w = 1.0 / var
        du, dv = rows[X, i] - x0, rows[Y, i] - y0
        a[0, k], a[1, k], a[2, k] = du, dv, 1.0
        aw[0, k], aw[1, k], aw[2, k] = du * w, dv * w, 1.0 * w
        b[k] = -(du * du + dv * dv)
    ok, inv = _inverse3(aw @ a.T)
    if not ok:
        return False, 0.0, 0.0, 0.0
    sol = inv @ (aw @ b)
    cu, cv = -0.5 * sol[0], -0.5 * sol[1]
    r2 = cu * cu + cv * cv - sol[2]
    if not (r2 > 0.0 and math.isfinite(r2)):
        return False, 0.0, 0.0, 0.0
    return True, cu + x0, cv + y0, math.sqrt(r2)


@compiled
def circle_problem(
    rows: FloatArray, start: int, stop: int, blur_rad: float
) -> tuple[FloatArray, int]:
    """The per-beam constants of the circle model of samples [start, stop), and the number
    of parameters fitted: 4 (cx, cy, r and the log reflectivity λ) when at least four
    samples carry usable intensities (positive weight and reflectivity), else 3.

    ``blur_rad`` is the angular σ over which the intensities are smoothed (see
    ``circle_model``).
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
        rng = rows[RANGE, i]
        if rows[WINT, i] > 0.0 and refl > 0.0 and rng > 0.0 and math.isfinite(math.log(refl)):
            p[_P_WINT, k] = rows[WINT, i]
            # log(I/(S cos θ)): the model's own range to the circle replaces the measured one
            # (see ``circle_model``).
            p[_P_LOGR, k] = math.log(refl) - 2.0 * math.log(rng)
            usable += 1
        else:
            p[_P_WINT, k] = 0.0
            p[_P_LOGR, k] = 0.0
        vx, vy = rows[VX, i], rows[VY, i]
        p[_P_VX, k], p[_P_VY, k], p[_P_VB, k] = vx, vy, vx * bx + vy * by
        p[_P_BLUR2, k] = blur_rad * blur_rad
    return p, 4 if usable >= 4 else 3


@compiled
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
    jacobian: bool = True,
) -> tuple[
    BoolArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, float, int
]:  # fmt: skip
    """The circle model (cx, cy, r, λ) of a :func:`circle_problem` (see ``circles.circle_fit``).

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
    jac = np.zeros((4, 2 * m if jacobian else 0))
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
        if jacobian:
            jac[0, i], jac[1, i], jac[2, i] = uxi, uyi, 1.0
        resid[i] = (flen - r) - (p[_P_LEN, i] - t) * ci
        weight[i] = 1.0 / vi if kept else 0.0
        if params == 4:
            vx, vy = p[_P_VX, i], p[_P_VY, i]
            cos_view = max(uxi * vx + uyi * vy, 1e-9)
            k = m + i
            t_pos = max(t, 1e-6)
            if jacobian:
                vb = p[_P_VB, i]
                half_i = max(half, 1e-9 * r)
                rcv = r * cos_view
                dtx = bx - (big_b * bx - ocx) / half_i  # ∂t/∂cx
                dty = by - (big_b * by - ocy) / half_i
                jac[0, k] = (vb * dtx - vx) / rcv - 2.0 * dtx / t_pos
                jac[1, k] = (vb * dty - vy) / rcv - 2.0 * dty / t_pos
                jac[2, k] = -vb / (half_i * cos_view) - 1.0 / r + 2.0 * r / (half_i * t_pos)
                jac[3, k] = 1.0
            w_int = p[_P_WINT, i] if (kept and ci >= intensity_min_cos) else 0.0
            # The smoothing: the footprint and the detection filter average the intensity over
            # an angle of σ ``blur_rad`` of the beam's sweep φ. The normal's direction turns
            # ω = dθ_u/dφ = k/cos ψ times faster (k = |c − o|/r, ψ the incidence), and
            # ω' = k² sin ψ/cos³ ψ; the profile cos ψ_v (ψ_v the viewing angle) averages to
            # its value times 1 + ½ blur² (cos ψ_v)''/cos ψ_v, (cos ψ_v)''/cos ψ_v =
            # −ω² − tan ψ_v ω' (second order in blur; not symmetric about the peak, as the
            # viewpoint lies a baseline to the side). A correction of a few 0.1 %, its
            # dependence on (c, r) is left out of the Jacobian.
            cpos = max(ci, 0.1)
            kk = (ocx * ocx + ocy * ocy) / (r * r)
            sin_inc = by * uxi - bx * uyi  # sin ψ, ψ from −b to u
            tan_view = (vx * uyi - vy * uxi) / cos_view  # tan ψ_v, ψ_v from v to u
            curvature = -kk / (cpos * cpos) * (1.0 + tan_view * sin_inc / cpos)
            blur = 0.5 * p[_P_BLUR2, i] * curvature
            g[i] = p[_P_LOGR, i] + 2.0 * math.log(t_pos) - math.log(cos_view) - blur
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


@compiled
def _normal_equations(
    resid: FloatArray, jac: FloatArray, weight: FloatArray, params: int
) -> tuple[float, FloatArray, FloatArray]:
    """χ² = Σ w e², the normal matrix Σ w a aᵀ and Σ w a e over the weighted residuals.

    Each sum is accumulated in residual order; the 4 × 4 (or 3 × 3) products are written
    out, as scalars, rather than looped over (the fit takes a sixth less time).
    """
    chi2 = 0.0
    r0 = r1 = r2 = r3 = 0.0
    n00 = n10 = n11 = n20 = n21 = n22 = n30 = n31 = n32 = n33 = 0.0
    four = params == 4
    for i in range(resid.size):
        wi = weight[i]
        if wi == 0.0:
            continue
        e = resid[i]
        chi2 += wi * e * e
        j0, j1, j2 = jac[0, i], jac[1, i], jac[2, i]
        wa = wi * j0
        r0 += wa * e
        n00 += wa * j0
        wa = wi * j1
        r1 += wa * e
        n10 += wa * j0
        n11 += wa * j1
        wa = wi * j2
        r2 += wa * e
        n20 += wa * j0
        n21 += wa * j1
        n22 += wa * j2
        if four:
            j3 = jac[3, i]
            wa = wi * j3
            r3 += wa * e
            n30 += wa * j0
            n31 += wa * j1
            n32 += wa * j2
            n33 += wa * j3
    normal = np.empty((params, params))
    rhs = np.empty(params)
    normal[0, 0], normal[1, 0], normal[1, 1] = n00, n10, n11
    normal[2, 0], normal[2, 1], normal[2, 2] = n20, n21, n22
    rhs[0], rhs[1], rhs[2] = r0, r1, r2
    if four:
        normal[3, 0], normal[3, 1], normal[3, 2], normal[3, 3] = n30, n31, n32, n33
        rhs[3] = r3
    for a in range(params):
        for b in range(a):
            normal[b, a] = normal[a, b]
    return chi2, normal, rhs


@compiled
def _chi2(resid: FloatArray, weight: FloatArray) -> float:
    """χ² = Σ w e², summed as :func:`_normal_equations` sums it (a trial step needs no more)."""
    chi2 = 0.0
    for i in range(resid.size):
        wi = weight[i]
        if wi != 0.0:
            e = resid[i]
            chi2 += wi * e * e
    return chi2


@compiled
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


@compiled
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
    blur_rad: float,
) -> tuple[bool, FloatArray, FloatArray, float, int, int, BoolArray, float]:
    """Gauss-Newton circle fit to samples [start, stop) from (cx, cy, r) (see
    ``agent.perception.features.circles.circle_fit``, which documents the model, the selection of
    beams, the stopping rules and the covariance).

    Returns (ok, q = (cx, cy, r), 3×3 covariance over q, χ², residuals in χ², parameters
    fitted, samples fitted, second largest range residual over its σ); ok False when the fit
    fails (see ``circles.circle_fit``).
    """
    p, params = circle_problem(rows, start, stop, blur_rad)
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
                # A trial needs its χ² alone (without the Jacobian the fit takes a seventh
                # less time): the one taken is evaluated in full below.
                trial = circle_model(
                    p, params, cand[0], cand[1], cand[2], cand_lam, True, keep, False,
                    everywhere, min_cos, intensity_min_cos, False,
                )  # fmt: skip
                t_chi2 = _chi2(trial[3], trial[5])
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
            keep, cos_inc, v, resid, jac, weight, lam, ints = circle_model(
                p, params, q[0], q[1], q[2], cand_lam, True, keep, False, everywhere,
                min_cos, intensity_min_cos,
            )  # fmt: skip
            chi2, normal, rhs = _normal_equations(resid, jac, weight, params)
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


def warm_up() -> None:
    """Load the circle kernels (compiling them on the first use on this machine)."""
    rows = example_rows()
    m = rows.shape[1]
    kasa(rows, 0, m)
    circle_fit(rows, 0, m, 1.3, 0.0, 0.2, 0.3, 1.0, 0.5, np.zeros(m - 1), 30, 3, 15.0, 1e-3)
