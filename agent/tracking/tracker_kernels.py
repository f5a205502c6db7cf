"""Compiled loops of :mod:`agent.tracking.tracker` (why compiled: :mod:`agent.compiled`).

The tracker's per-scan steps are small (a few dozen tracks, a handful of features) but many:
in numpy each costs a dozen array calls of a microsecond or more whatever their size, and
together they took several milliseconds a scan. These loops do the same arithmetic, in the
order the formulas beside the numpy references (:mod:`agent.tracking.filters`,
:func:`agent.tracking.geometry.pose_noise_increment`) state it.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from agent.arrays import FloatArray
from agent.compiled import compiled, compiled_inline

BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]


@compiled
def pose_noise_increment(
    cov_then: FloatArray, cov_now: FloatArray, dx_m: float, dy_m: float
) -> FloatArray:
    """``Σ_now − F·Σ_then·Fᵀ`` clipped to positive semi-definite (see
    :func:`agent.tracking.geometry.pose_noise_increment`)."""
    F = np.eye(3)
    F[0, 2] = -dy_m
    F[1, 2] = dx_m
    d = cov_now - F @ cov_then @ F.T
    d = 0.5 * (d + d.T)
    w, v = np.linalg.eigh(d)
    out = np.zeros((3, 3))
    for k in range(3):
        if w[k] > 0.0:
            for i in range(3):
                for j in range(3):
                    out[i, j] += w[k] * v[i, k] * v[j, k]
    return out


@compiled_inline
def _eigenvalues_2x2(a: float, b: float, c: float) -> tuple[float, float]:
    """The larger and smaller eigenvalue of the symmetric 2 × 2 matrix [[a, b], [b, c]]."""
    mid = 0.5 * (a + c)
    rad = math.sqrt(0.25 * (a - c) * (a - c) + b * b)
    return mid + rad, mid - rad


@compiled
def drift_increment(
    points: FloatArray,
    vehicle_xy: FloatArray,
    epoch_cov: FloatArray,
    epoch: IntArray,
    drift: FloatArray,
) -> FloatArray:
    """(k, 3, 3) the odometry's drift to add to ``k`` point tracks this scan, only the
    (x, y) block set, and ``drift`` (k, 3, 3) grown by it in place (see
    :meth:`agent.tracking.tracker.Tracker._drift_increment`).

    For track ``r`` at ``points[r]`` whose epoch is ``epoch[r]``: the target
    ``J·Σ·Jᵀ`` of :func:`agent.tracking.geometry.point_drift_noise` with
    ``Σ = epoch_cov[epoch[r]]``, less what ``drift[r]`` already holds, clipped to its
    positive part. For a symmetric 2 × 2 ``M`` with eigenvalues ``λ₁ ≥ λ₂``: ``M`` itself
    when ``λ₂ ≥ 0``, nothing when ``λ₁ ≤ 0``, else ``λ₁·(M − λ₂I)/(λ₁ − λ₂)``.
    """
    k = points.shape[0]
    out = np.zeros((k, 3, 3))
    for r in range(k):
        S = epoch_cov[epoch[r]]
        l0 = vehicle_xy[1] - points[r, 1]
        l1 = points[r, 0] - vehicle_xy[0]
        t00 = S[0, 0] + 2.0 * l0 * S[0, 2] + S[2, 2] * l0 * l0
        t01 = S[0, 1] + l0 * S[1, 2] + l1 * S[0, 2] + S[2, 2] * l0 * l1
        t10 = S[1, 0] + l1 * S[0, 2] + l0 * S[1, 2] + S[2, 2] * l1 * l0
        t11 = S[1, 1] + 2.0 * l1 * S[1, 2] + S[2, 2] * l1 * l1
        a = t00 - drift[r, 0, 0]
        c = t11 - drift[r, 1, 1]
        b = 0.5 * ((t01 - drift[r, 0, 1]) + (t10 - drift[r, 1, 0]))
        hi, lo = _eigenvalues_2x2(a, b, c)
        if hi <= 0.0:
            continue
        if lo < 0.0:
            f = hi / (hi - lo)
            a, b, c = f * (a - lo), f * b, f * (c - lo)
        out[r, 0, 0], out[r, 0, 1], out[r, 1, 0], out[r, 1, 1] = a, b, b, c
        drift[r, 0, 0] += a
        drift[r, 0, 1] += b
        drift[r, 1, 0] += b
        drift[r, 1, 1] += c
    return out


@compiled
def imm_predict(
    xm: FloatArray,
    Pm: FloatArray,
    mu: FloatArray,
    Pi: FloatArray,
    dt: float,
    accel_psd: float,
    static_velocity_var: float,
    vehicle_xy: FloatArray,
    delta_cov: FloatArray,
    held: BoolArray,
    stationary: FloatArray,
    initial_velocity_var: float,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The static/CV IMM's mixing and prediction over ``dt`` for ``k`` tracks.

    ``xm (k, 2, 4)``, ``Pm (k, 2, 4, 4)``, ``mu (k, 2)``, ``Pi (2, 2)`` as
    :func:`agent.tracking.filters.imm_mix`; then model 0 (static: position kept, velocity
    zero plus ``static_velocity_var``) and model 1 (CV, white acceleration ``accel_psd``,
    :func:`agent.tracking.filters.cv_process_noise`); both get the odometry's drift noise
    ``J·ΔΣ·Jᵀ`` at the mixed position (:func:`agent.tracking.geometry.point_drift_noise`),
    ``ΔΣ = delta_cov[t]`` (k, 3, 3), one per track.
    Tracks where ``held`` get their CV model re-armed from the static one (velocity
    variance ``initial_velocity_var``, probabilities ``stationary``).
    """
    k = xm.shape[0]
    x = np.empty_like(xm)
    P = np.empty_like(Pm)
    c_out = np.empty_like(mu)
    q = accel_psd
    qa, qb, qc = q * dt**3 / 3.0, q * dt**2 / 2.0, q * dt
    for t in range(k):
        c0 = mu[t, 0] * Pi[0, 0] + mu[t, 1] * Pi[1, 0]
        c1 = mu[t, 0] * Pi[0, 1] + mu[t, 1] * Pi[1, 1]
        c = (c0, c1)
        x0 = np.zeros((2, 4))
        P0 = np.zeros((2, 4, 4))
        for j in range(2):
            cj = max(c[j], 1e-300)
            for i in range(2):
                w = mu[t, i] * Pi[i, j] / cj
                for a in range(4):
                    x0[j, a] += w * xm[t, i, a]
            for i in range(2):
                w = mu[t, i] * Pi[i, j] / cj
                for a in range(4):
                    da = xm[t, i, a] - x0[j, a]
                    for b in range(4):
                        P0[j, a, b] += w * (Pm[t, i, a, b] + da * (xm[t, i, b] - x0[j, b]))
        # Static model: F = diag(1, 1, 0, 0).
        for a in range(4):
            for b in range(4):
                P[t, 0, a, b] = P0[0, a, b] if (a < 2 and b < 2) else 0.0
        x[t, 0, 0], x[t, 0, 1], x[t, 0, 2], x[t, 0, 3] = x0[0, 0], x0[0, 1], 0.0, 0.0
        P[t, 0, 2, 2] = static_velocity_var
        P[t, 0, 3, 3] = static_velocity_var
        # CV model: F = [[I, dt·I], [0, I]], P = F·P0·Fᵀ + Q.
        F = np.eye(4)
        F[0, 2] = dt
        F[1, 3] = dt
        Pc = F @ P0[1] @ F.T
        for a in range(4):
            x[t, 1, a] = x0[1, a]
        x[t, 1, 0] += dt * x0[1, 2]
        x[t, 1, 1] += dt * x0[1, 3]
        Pc[0, 0] += qa
        Pc[1, 1] += qa
        Pc[0, 2] += qb
        Pc[2, 0] += qb
        Pc[1, 3] += qb
        Pc[3, 1] += qb
        Pc[2, 2] += qc
        Pc[3, 3] += qc
        P[t, 1] = Pc
        # Drift of odom: J = [I | L] at the mixed position, L = (−(p_y − v_y), p_x − v_x).
        px = c0 * x[t, 0, 0] + c1 * x[t, 1, 0]
        py = c0 * x[t, 0, 1] + c1 * x[t, 1, 1]
        L0 = vehicle_xy[1] - py
        L1 = px - vehicle_xy[0]
        L = (L0, L1)
        for a in range(2):
            for b in range(2):
                qd = (
                    delta_cov[t, a, b]
                    + L[a] * delta_cov[t, 2, b]
                    + delta_cov[t, a, 2] * L[b]
                    + delta_cov[t, 2, 2] * L[a] * L[b]
                )
                P[t, 0, a, b] += qd
                P[t, 1, a, b] += qd
        c_out[t, 0], c_out[t, 1] = c0, c1
        if held[t]:
            x[t, 1] = x[t, 0]
            P[t, 1] = P[t, 0]
            P[t, 1, 2, 2] = initial_velocity_var
            P[t, 1, 3, 3] = initial_velocity_var
            c_out[t, 0], c_out[t, 1] = stationary[0], stationary[1]
    return x, P, c_out


@compiled
def decide(
    updated: BoolArray,
    visible: BoolArray,
    hits: IntArray,
    misses: IntArray,
    visible_scans: IntArray,
    confirmed: BoolArray,
    last_seen_ns: IntArray,
    moving: BoolArray,
    stamp_ns: int,
    confirm_hits: int,
    confirm_hits_moving: int,
    confirm_window: int,
    delete_misses: int,
    delete_misses_moving: int,
    max_coast_moving_s: float,
    tentative_timeout_s: float,
) -> tuple[BoolArray, int]:
    """Misses, confirmation (M of N over expected-visible scans) and deletion, in place on
    ``misses``, ``visible_scans`` and ``confirmed``; returns the tracks to drop and the
    count newly confirmed (rules: :mod:`agent.tracking.tracker`)."""
    k = updated.shape[0]
    drop = np.zeros(k, dtype=np.bool_)
    newly = 0
    for t in range(k):
        missed = visible[t] and not updated[t]
        misses[t] = 0 if updated[t] else misses[t] + (1 if missed else 0)
        if missed or (updated[t] and hits[t] > 1):
            visible_scans[t] += 1
        need = confirm_hits_moving if moving[t] else confirm_hits
        if not confirmed[t] and hits[t] >= need and visible_scans[t] <= confirm_window:
            confirmed[t] = True
            newly += 1
        unseen_s = (stamp_ns - last_seen_ns[t]) * 1e-9
        if confirmed[t]:
            if moving[t]:
                drop[t] = misses[t] >= delete_misses_moving or unseen_s > max_coast_moving_s
            else:
                drop[t] = misses[t] >= delete_misses
        else:
            hopeless = visible_scans[t] - hits[t] > confirm_window - confirm_hits
            drop[t] = hopeless or unseen_s > tentative_timeout_s
    return drop, newly


@compiled
def valid_features(
    kind: NDArray[np.uint8], params: FloatArray, cov: FloatArray, endpoints: FloatArray
) -> BoolArray:
    """See :func:`agent.tracking.tracker.valid_features`."""
    k = kind.shape[0]
    ok = np.zeros(k, dtype=np.bool_)
    for f in range(k):
        if kind[f] > 3:
            continue
        dof = 3 if kind[f] == 3 else 2
        good = True
        for i in range(dof):
            if not math.isfinite(params[f, i]):
                good = False
            for j in range(dof):
                if not math.isfinite(cov[f, i, j]):
                    good = False
        if not good:
            continue
        for i in range(dof):
            for j in range(i + 1, dof):
                tol = 1e-9 * math.sqrt(abs(cov[f, i, i] * cov[f, j, j]))
                if abs(cov[f, i, j] - cov[f, j, i]) > tol:
                    good = False
        # Sylvester: every leading minor positive.
        m1 = cov[f, 0, 0]
        m2 = cov[f, 0, 0] * cov[f, 1, 1] - cov[f, 0, 1] * cov[f, 1, 0]
        if not (good and m1 > 0.0 and m2 > 0.0):
            continue
        if dof == 3 and (np.linalg.det(cov[f]) <= 0.0 or not params[f, 2] > 0.0):
            continue
        if kind[f] == 0:
            for i in range(2):
                for j in range(2):
                    if not math.isfinite(endpoints[f, i, j]):
                        good = False
        ok[f] = good
    return ok


def warm_up() -> None:
    """Load (on a new machine: compile) every kernel here with the tracker's argument types."""
    eye = np.eye(3)
    pose_noise_increment(eye, eye, 0.0, 0.0)
    k = 1
    drift_increment(
        np.zeros((k, 2)), np.zeros(2), np.zeros((k, 3, 3)), np.zeros(k, dtype=np.int64),
        np.zeros((k, 3, 3)),
    )  # fmt: skip
    floor_position(np.zeros((k, 4, 4)), np.zeros(k, dtype=np.int64), 0.003)
    floor_position(np.zeros((k, 2, 2)), np.zeros(k, dtype=np.int64), 0.003)
    one = np.ones(k, dtype=np.int64)
    hit(
        np.zeros(k, dtype=np.int64), np.zeros(k), 0, np.zeros((k, 3, 3)), one.copy(),
        np.zeros(k, dtype=np.bool_), one.copy(), np.zeros(k), one.copy(),
    )  # fmt: skip
    feature_times(np.zeros((k, 2)), np.ones(k), np.zeros((k, 2)), np.zeros(k), 0.03)
    point_view_inputs(
        np.zeros((k, 2)), np.tile(np.eye(2), (k, 1, 1)), np.zeros(k, dtype=np.bool_),
        np.zeros((k, 2, 4)), np.zeros((k, 2, 4, 4)), np.full((k, 2), 0.5), np.ones(k), np.zeros(k),
        np.zeros(k, dtype=np.bool_), np.zeros(3), 0.1, 5, 5, 0.5, 0.5, 0.25,
    )  # fmt: skip
    none = np.zeros(0, dtype=np.int64)
    add_line_drift(np.zeros((k, 2, 2)), np.zeros((k, 2)), np.zeros(2), eye)
    bound_speeds(np.zeros((k, 2, 4)), np.zeros((k, 2, 4, 4)), 1.0)
    flags = np.zeros(k, dtype=np.bool_)
    common_outputs(flags, flags, np.zeros(k), np.zeros(k, dtype=np.int64), 0, 2, 1)
    P2 = np.tile(np.eye(2), (k, 1, 1))
    cylinder_costs(
        np.zeros((k, 2)), P2, np.zeros(k), np.zeros(k), np.zeros((k, 2, 4)),
        np.tile(np.eye(4), (k, 2, 1, 1)), 1.0, np.ones(k), np.ones(k), np.ones(k), np.ones(k),
    )  # fmt: skip
    new_cylinders(np.zeros((k, 2)), P2, np.zeros(k), none, 1e-4, 0.25, 2.0)
    fuse_radius(np.ones(k), np.ones(k), none, np.ones(k), np.ones(k), 1e-4)
    ends, seen = np.zeros((k, 2, 2)), np.zeros((k, 2), dtype=np.bool_)
    extents_near(np.zeros((k, 2)), ends, ends, 0.3)
    merge_extents(np.zeros((k, 2)), ends, seen, none, ends, seen)
    new_segments(np.zeros(k), np.zeros(k), ends, seen, none)
    assignment_rest(
        none, none, np.zeros((k, k)), np.ones((k, k), np.bool_), np.ones((k, k), np.bool_)
    )
    keep_epochs(
        np.zeros(2, dtype=np.int64), np.zeros((2, 27, 3)), np.zeros((2, 3, 3)), 1,
        np.zeros(k, dtype=np.int64), np.zeros(k, dtype=np.int64), 0, np.zeros(3),
    )  # fmt: skip
    cylinder_outputs(
        np.zeros((k, 2, 4)), np.zeros((k, 2, 4, 4)), np.full((k, 2), 0.5), np.ones(k),
        np.ones(k), 0, np.zeros((k, 4)), np.zeros((k, 4, 4)), np.zeros((k, 3)),
        np.zeros((k, 3, 3)), np.zeros((k, 4)), np.zeros(k),
    )  # fmt: skip
    imm_predict(
        np.zeros((k, 2, 4)), np.tile(np.eye(4), (k, 2, 1, 1)), np.full((k, 2), 0.5), np.eye(2),
        0.1, 1.0, 1e-4, np.zeros(2), np.zeros((k, 3, 3)), np.zeros(k, dtype=np.bool_),
        np.array([0.9, 0.1]), 0.25,
    )  # fmt: skip
    b = np.zeros(k, dtype=np.bool_)
    i = np.zeros(k, dtype=np.int64)
    decide(b, b, i, i.copy(), i.copy(), b.copy(), i.copy(), b, 0, 3, 2, 5, 8, 3, 2.0, 0.5)
    valid_features(
        np.zeros(k, dtype=np.uint8), np.zeros((k, 3)), np.tile(eye, (k, 1, 1)),
        np.zeros((k, 2, 2)),
    )  # fmt: skip
    point_costs(np.zeros((k, 2)), P2, np.zeros((k, 2)), P2)
    point_costs(np.zeros((k, 2)), P2, np.zeros((k, 4)), np.tile(np.eye(4), (k, 1, 1)))
    line_costs(np.zeros(k), np.ones(k), P2, np.zeros((k, 2)), P2)
    imm_combine(np.zeros((k, 2, 4)), np.zeros((k, 2, 4, 4)), np.full((k, 2), 0.5))
    position_log_dets(P2, np.zeros(k, dtype=np.int64))
    add_information(np.zeros(k), np.zeros(k, dtype=np.int64), np.zeros(k), np.zeros(k))
    rows = np.zeros(k, dtype=np.int64)
    kf_update(np.zeros((k, 2)), P2.copy(), rows, np.zeros((k, 2)), P2, True)
    imm_update(
        np.zeros((k, 2, 4)), np.tile(np.eye(4), (k, 2, 1, 1)), np.full((k, 2), 0.5), rows,
        np.zeros((k, 2)), P2, 1e-6,
    )  # fmt: skip
    imm_update_timed(
        np.zeros((k, 2, 4)), np.tile(np.eye(4), (k, 2, 1, 1)), np.full((k, 2), 0.5), rows,
        np.zeros((k, 2)), P2, np.zeros(k), np.zeros(k), 1.0, 1e-6,
    )  # fmt: skip
    point_costs_timed(
        np.zeros((k, 2)), P2, np.zeros(k), np.zeros(k), np.zeros((k, 4)),
        np.tile(np.eye(4), (k, 1, 1)), 1.0,
    )  # fmt: skip
    lines_to_base(np.ones((k, 2)), P2, np.ones((k, 2, 2)), np.zeros(3))
    segment_outputs(
        np.ones((k, 2)), P2, np.ones((k, 2, 2)), np.zeros((k, 2), dtype=np.bool_), 0.05,
        np.zeros((k, 4)), np.zeros((k, 4, 4)), np.zeros((k, 3)), np.zeros((k, 3, 3)),
        np.zeros((k, 4)), np.zeros((k, 2), dtype=np.uint8),
    )  # fmt: skip


@compiled
def point_costs(
    z: FloatArray, R: FloatArray, x: FloatArray, P: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Gating of ``m`` point features ``z (m, 2)``, ``R (m, 2, 2)`` against ``k`` tracks'
    predicted positions ``x (k, ≥2)``, ``P (k, ≥2, ≥2)`` (their first two components):
    ``d² = νᵀ·S⁻¹·ν`` and the cost ``d² + ln det S`` with ``S = P + R``, each (k, m); inf
    where ``S`` is not positive definite."""
    k, m = x.shape[0], z.shape[0]
    d2 = np.empty((k, m))
    cost = np.empty((k, m))
    for t in range(k):
        for j in range(m):
            a = P[t, 0, 0] + R[j, 0, 0]
            b = P[t, 0, 1] + R[j, 0, 1]
            c = P[t, 1, 0] + R[j, 1, 0]
            d = P[t, 1, 1] + R[j, 1, 1]
            det = a * d - b * c
            n0 = z[j, 0] - x[t, 0]
            n1 = z[j, 1] - x[t, 1]
            if det > 0.0 and a > 0.0:
                q = (d * n0 * n0 - (b + c) * n0 * n1 + a * n1 * n1) / det
                d2[t, j] = q
                cost[t, j] = q + math.log(det)
            else:
                d2[t, j] = np.inf
                cost[t, j] = np.inf
    return d2, cost


@compiled
def line_costs(
    alpha: FloatArray, rho: FloatArray, R: FloatArray, x: FloatArray, P: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, BoolArray]:
    """Gating of ``m`` line features (α, ρ) with ``R (m, 2, 2)`` against ``k`` line tracks
    ``x (k, 2)``, ``P (k, 2, 2)``: each feature written within a quarter turn of the track's
    α (:func:`agent.tracking.geometry.align_lines`; a flip negates ρ and the α-ρ
    covariance). Returns ``d²`` and cost (k, m) as :func:`point_costs`, the innovations
    ``ν (k, m, 2)`` (α wrapped) and the flips (k, m)."""
    k, m = x.shape[0], alpha.shape[0]
    d2 = np.empty((k, m))
    cost = np.empty((k, m))
    nu = np.empty((k, m, 2))
    flip = np.zeros((k, m), dtype=np.bool_)
    two_pi = 2.0 * math.pi
    for t in range(k):
        for j in range(m):
            da = alpha[j] - x[t, 0]
            da -= two_pi * math.floor(da / two_pi + 0.5)
            r = rho[j]
            s = 1.0
            if abs(da) > 0.5 * math.pi:
                flip[t, j] = True
                da = da - math.pi if da > 0.0 else da + math.pi
                r = -r
                s = -1.0
            n0, n1 = da, r - x[t, 1]
            nu[t, j, 0], nu[t, j, 1] = n0, n1
            a = P[t, 0, 0] + R[j, 0, 0]
            b = P[t, 0, 1] + s * R[j, 0, 1]
            c = P[t, 1, 0] + s * R[j, 1, 0]
            d = P[t, 1, 1] + R[j, 1, 1]
            det = a * d - b * c
            if det > 0.0 and a > 0.0:
                q = (d * n0 * n0 - (b + c) * n0 * n1 + a * n1 * n1) / det
                d2[t, j] = q
                cost[t, j] = q + math.log(det)
            else:
                d2[t, j] = np.inf
                cost[t, j] = np.inf
    return d2, cost, nu, flip


@compiled
def position_log_dets(P: FloatArray, rows: IntArray) -> FloatArray:
    """(r,) ``ln det`` of the leading 2 × 2 block of ``P[t]`` (k, n, n) for each ``t`` in
    ``rows`` (a point's x, y; a line's α, ρ); −inf where it is not positive."""
    out = np.empty(rows.shape[0])
    for q in range(rows.shape[0]):
        t = rows[q]
        det = P[t, 0, 0] * P[t, 1, 1] - P[t, 0, 1] * P[t, 1, 0]
        out[q] = math.log(det) if det > 0.0 else -np.inf
    return out


@compiled
def add_information(
    bits: FloatArray, rows: IntArray, log_det_before: FloatArray, log_det_after: FloatArray
) -> None:
    """In place: ``bits[t] += ½·log₂(det P⁻ / det P⁺)`` for each ``t`` in ``rows``, its
    positive part (a σ floor, or a mixture whose models moved apart, can widen what an
    update narrowed); nothing where either determinant is not positive."""
    for q in range(rows.shape[0]):
        before, after = log_det_before[q], log_det_after[q]
        if math.isfinite(before) and math.isfinite(after) and before > after:
            bits[rows[q]] += 0.5 * (before - after) / math.log(2.0)


@compiled
def imm_combine(xm: FloatArray, Pm: FloatArray, mu: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Moment-matched estimate (k, 4), (k, 4, 4) of the IMM's two models (see
    :func:`agent.tracking.filters.imm_combine`)."""
    k = xm.shape[0]
    x = np.zeros((k, 4))
    P = np.zeros((k, 4, 4))
    for t in range(k):
        for i in range(2):
            for a in range(4):
                x[t, a] += mu[t, i] * xm[t, i, a]
        for i in range(2):
            for a in range(4):
                da = xm[t, i, a] - x[t, a]
                for b in range(4):
                    P[t, a, b] += mu[t, i] * (Pm[t, i, a, b] + da * (xm[t, i, b] - x[t, b]))
    return x, P


@compiled
def segment_outputs(
    x: FloatArray,
    P: FloatArray,
    ends: FloatArray,
    seen: BoolArray,
    end_sigma_m: float,
    state: FloatArray,
    cov: FloatArray,
    params: FloatArray,
    pcov: FloatArray,
    extent: FloatArray,
    end_seen: NDArray[np.uint8],
) -> None:
    """Fill the first ``k`` rows of the ``tracks`` arrays for segment tracks (lines
    ``x (k, 2)``, ``P (k, 2, 2)``, end points ``ends (k, 2, 2)`` with ``seen (k, 2)``).

    The extent is the end points projected on the line; the reference point its midpoint,
    with the line's variance across (``δ = δρ − u·δα`` at along-coordinate ``u``) and
    along ``end_sigma_m²`` when both ends were seen, else the extent's length²/12 (but no
    less); the line as ``ρ ≥ 0`` (a flip negates the α-ρ covariance), its ρ variance with
    the second-order term ``½ρ²σ_α⁴`` (as ``agent.perception.features.lines.Line.
    reported_cov`` for ``base_link``).
    """
    k = x.shape[0]
    for t in range(k):
        a, r = x[t, 0], x[t, 1]
        c, s = math.cos(a), math.sin(a)
        u0 = -ends[t, 0, 0] * s + ends[t, 0, 1] * c
        u1 = -ends[t, 1, 0] * s + ends[t, 1, 1] * c
        for e, u in ((0, u0), (1, u1)):
            extent[t, 2 * e] = r * c - u * s
            extent[t, 2 * e + 1] = r * s + u * c
            end_seen[t, e] = 1 if seen[t, e] else 0
        um = 0.5 * (u0 + u1)
        state[t, 0] = r * c - um * s
        state[t, 1] = r * s + um * c
        if seen[t, 0] and seen[t, 1]:
            var_along = end_sigma_m**2
        else:
            var_along = max((u1 - u0) ** 2 / 12.0, end_sigma_m**2)
        var_across = P[t, 1, 1] - 2.0 * um * P[t, 0, 1] + um * um * P[t, 0, 0]
        cov[t, 0, 0] = var_across * c * c + var_along * s * s
        cov[t, 1, 1] = var_across * s * s + var_along * c * c
        cov[t, 0, 1] = cov[t, 1, 0] = (var_across - var_along) * c * s
        sign = -1.0 if r < 0.0 else 1.0
        aa = a + math.pi if r < 0.0 else a
        params[t, 0] = aa - 2.0 * math.pi * math.floor(aa / (2.0 * math.pi) + 0.5)
        params[t, 1] = sign * r
        pcov[t, 0, 0] = P[t, 0, 0]
        # ρ's second-order error, −½ρ(δα² − σ_α²) (the line turning about its extent),
        # whose variance is ½ρ²σ_α⁴: a line far from the odom origin is not linear in α.
        pcov[t, 1, 1] = P[t, 1, 1] + 0.5 * (r * P[t, 0, 0]) ** 2
        pcov[t, 0, 1] = pcov[t, 1, 0] = sign * P[t, 0, 1]


@compiled
def kf_update(
    x: FloatArray,
    P: FloatArray,
    rows: IntArray,
    nu: FloatArray,
    R: FloatArray,
    wrap_first: bool,
) -> None:
    """In place: the Kalman update of tracks ``rows`` of ``x (k, n)``, ``P (k, n, n)`` with
    innovations ``nu (r, 2)`` of their first two components and ``R (r, 2, 2)``
    (:func:`agent.tracking.filters.update_first_two`); ``wrap_first`` wraps the first
    component (a line's α) to [-π, π) after."""
    for q in range(rows.shape[0]):
        t = rows[q]
        K, _, _ = _gain(P[t], R[q])
        _apply(x[t], P[t], K, nu[q], R[q])
        if wrap_first:
            x[t, 0] -= 2.0 * math.pi * math.floor(x[t, 0] / (2.0 * math.pi) + 0.5)


@compiled_inline
def _gain(P: FloatArray, R: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    """Gain ``K = P·Hᵀ·S⁻¹`` (n, 2), ``S⁻¹`` and ``det S`` for ``H = [I₂ 0]``."""
    n = P.shape[0]
    a = P[0, 0] + R[0, 0]
    b = P[0, 1] + R[0, 1]
    c = P[1, 0] + R[1, 0]
    d = P[1, 1] + R[1, 1]
    det = a * d - b * c
    Si = np.empty((2, 2))
    Si[0, 0], Si[0, 1], Si[1, 0], Si[1, 1] = d / det, -b / det, -c / det, a / det
    K = np.empty((n, 2))
    for i in range(n):
        K[i, 0] = P[i, 0] * Si[0, 0] + P[i, 1] * Si[1, 0]
        K[i, 1] = P[i, 0] * Si[0, 1] + P[i, 1] * Si[1, 1]
    return K, Si, det


@compiled_inline
def _apply(x: FloatArray, P: FloatArray, K: FloatArray, nu: FloatArray, R: FloatArray) -> None:
    """``x += K·ν``, ``P −= K·S·Kᵀ`` (``S = P₂₂ + R``), symmetrised; in place."""
    n = x.shape[0]
    S = np.empty((2, 2))
    for i in range(2):
        for j in range(2):
            S[i, j] = P[i, j] + R[i, j]
    for i in range(n):
        x[i] += K[i, 0] * nu[0] + K[i, 1] * nu[1]
    KS = np.empty((n, 2))
    for i in range(n):
        KS[i, 0] = K[i, 0] * S[0, 0] + K[i, 1] * S[1, 0]
        KS[i, 1] = K[i, 0] * S[0, 1] + K[i, 1] * S[1, 1]
    for i in range(n):
        for j in range(n):
            P[i, j] -= KS[i, 0] * K[j, 0] + KS[i, 1] * K[j, 1]
    for i in range(n):
        for j in range(i + 1, n):
            m = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = m
            P[j, i] = m


@compiled
def imm_update(
    xm: FloatArray,
    Pm: FloatArray,
    mu: FloatArray,
    rows: IntArray,
    z: FloatArray,
    R: FloatArray,
    min_probability: float,
) -> None:
    """In place: the IMM update of tracks ``rows`` with positions ``z (r, 2)``, ``R
    (r, 2, 2)``: each model's Kalman update, and the model probabilities in proportion to
    ``μ·N(ν; 0, S)``, each kept above ``min_probability`` (a model at exactly 0 could never
    come back) and renormalised."""
    for q in range(rows.shape[0]):
        t = rows[q]
        logw = np.empty(2)
        for i in range(2):
            nu = np.empty(2)
            nu[0] = z[q, 0] - xm[t, i, 0]
            nu[1] = z[q, 1] - xm[t, i, 1]
            K, Si, det = _gain(Pm[t, i], R[q])
            d2 = (
                nu[0] * nu[0] * Si[0, 0]
                + nu[0] * nu[1] * (Si[0, 1] + Si[1, 0])
                + nu[1] * nu[1] * Si[1, 1]
            )
            logw[i] = math.log(max(mu[t, i], 1e-300)) - 0.5 * (d2 + math.log(det))
            _apply(xm[t, i], Pm[t, i], K, nu, R[q])
        top = max(logw[0], logw[1])
        w0, w1 = math.exp(logw[0] - top), math.exp(logw[1] - top)
        p0, p1 = w0 / (w0 + w1), w1 / (w0 + w1)
        p0, p1 = max(p0, min_probability), max(p1, min_probability)
        mu[t, 0], mu[t, 1] = p0 / (p0 + p1), p1 / (p0 + p1)


@compiled
def lines_to_base(
    x: FloatArray, P: FloatArray, ends: FloatArray, pose: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Line tracks (α, ρ) in ``odom`` with end points ``ends (k, 2, 2)`` written in
    ``base_link`` at ``pose``: α, ρ, the extent's along-line interval (lo, hi) and a σ for
    visibility margins (ρ's plus 2.5 × α's in metres per radian, a few metres' lever)."""
    k = x.shape[0]
    a_b = np.empty(k)
    rho_b = np.empty(k)
    lo = np.empty(k)
    hi = np.empty(k)
    sigma = np.empty(k)
    cy, sy = math.cos(pose[2]), math.sin(pose[2])
    for t in range(k):
        a = x[t, 0] - pose[2]
        a -= 2.0 * math.pi * math.floor(a / (2.0 * math.pi) + 0.5)
        a_b[t] = a
        rho_b[t] = x[t, 1] - (pose[0] * math.cos(x[t, 0]) + pose[1] * math.sin(x[t, 0]))
        c, s = math.cos(a), math.sin(a)
        us = np.empty(2)
        for e in range(2):
            dx, dy = ends[t, e, 0] - pose[0], ends[t, e, 1] - pose[1]
            bx, by = cy * dx + sy * dy, -sy * dx + cy * dy
            us[e] = -bx * s + by * c
        lo[t], hi[t] = min(us[0], us[1]), max(us[0], us[1])
        sigma[t] = math.sqrt(max(P[t, 1, 1], 0.0)) + 2.5 * math.sqrt(max(P[t, 0, 0], 0.0))
    return a_b, rho_b, lo, hi, sigma


@compiled_inline
def _timed_terms(
    x: FloatArray,
    P: FloatArray,
    z: FloatArray,
    R: FloatArray,
    tau: float,
    smear_var: float,
    accel_psd: float,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """For a (x, y, vx, vy) state measured at ``tau`` s before its time (``H = [I₂, −τ·I₂]``):
    the innovation ``ν = z − H·x`` (2,), the cross-covariance ``C = (P − Q(τ))·Hᵀ`` (4, 2)
    and ``S = H·(P − Q(τ))·Hᵀ + R + R_smear`` (2, 2).

    ``Q(τ)`` is the white-acceleration noise (``accel_psd``, 0 for the static model) of the
    last ``τ`` s, which the state at its time holds and the measurement, taken before it,
    does not: this is exactly predicting to the measurement's time, updating there and
    predicting on (``x(t) = F(τ)·x(t−τ) + w``, ``w ~ Q(τ)``, so ``z = H·x(t) − H·w + n`` with
    ``Cov(x(t), w) = Q(τ)``). ``R_smear = smear_var·(v·vᵀ + P_vv)`` is the centre's error
    from fitting one circle to samples taken over a spread of times (variance ``smear_var``
    s²) by a target moving at ``v``."""
    qa = accel_psd * tau**3 / 3.0
    qb = accel_psd * tau**2 / 2.0
    qc = accel_psd * tau
    Pq = P.copy()
    for a in range(2):
        Pq[a, a] -= qa
        Pq[a, a + 2] -= qb
        Pq[a + 2, a] -= qb
        Pq[a + 2, a + 2] -= qc
    PHt = np.empty((4, 2))
    for a in range(4):
        for b in range(2):
            PHt[a, b] = Pq[a, b] - tau * Pq[a, b + 2]
    S = np.empty((2, 2))
    for a in range(2):
        for b in range(2):
            S[a, b] = (
                PHt[a, b]
                - tau * PHt[a + 2, b]
                + R[a, b]
                + smear_var * (x[a + 2] * x[b + 2] + Pq[a + 2, b + 2])
            )
    nu = np.empty(2)
    nu[0] = z[0] - (x[0] - tau * x[2])
    nu[1] = z[1] - (x[1] - tau * x[3])
    return nu, PHt, S


@compiled
def point_costs_timed(
    z: FloatArray,
    R: FloatArray,
    tau: FloatArray,
    smear_var: FloatArray,
    x: FloatArray,
    P: FloatArray,
    accel_psd: float,
) -> tuple[FloatArray, FloatArray]:
    """As :func:`point_costs` for ``k`` (x, y, vx, vy) tracks ``x (k, 4)``, ``P (k, 4, 4)``
    and ``m`` features measured ``tau (m,)`` s before the tracks' time, with the smear
    variance ``smear_var (m,)`` s² and the model's ``accel_psd`` (:func:`_timed_terms`)."""
    k, m = x.shape[0], z.shape[0]
    d2 = np.empty((k, m))
    cost = np.empty((k, m))
    for t in range(k):
        for j in range(m):
            nu, _, S = _timed_terms(x[t], P[t], z[j], R[j], tau[j], smear_var[j], accel_psd)
            det = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
            if det > 0.0 and S[0, 0] > 0.0:
                q = (
                    S[1, 1] * nu[0] * nu[0]
                    - (S[0, 1] + S[1, 0]) * nu[0] * nu[1]
                    + S[0, 0] * nu[1] * nu[1]
                ) / det
                d2[t, j] = q
                cost[t, j] = q + math.log(det)
            else:
                d2[t, j] = np.inf
                cost[t, j] = np.inf
    return d2, cost


@compiled
def imm_update_timed(
    xm: FloatArray,
    Pm: FloatArray,
    mu: FloatArray,
    rows: IntArray,
    z: FloatArray,
    R: FloatArray,
    tau: FloatArray,
    smear_var: FloatArray,
    accel_psd: float,
    min_probability: float,
) -> None:
    """:func:`imm_update` for features measured ``tau (r,)`` s before the tracks' time, with
    the smear variance ``smear_var (r,)`` s² (:func:`_timed_terms`; the CV model, 1, with
    ``accel_psd``, the static one with none): each model's Kalman update with
    ``H = [I₂, −τ·I₂]``, ``K = C·S⁻¹``, ``P −= K·S·Kᵀ``."""
    for q in range(rows.shape[0]):
        t = rows[q]
        logw = np.empty(2)
        for i in range(2):
            nu, PHt, S = _timed_terms(
                xm[t, i], Pm[t, i], z[q], R[q], tau[q], smear_var[q], accel_psd * i
            )
            det = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
            if not (det > 0.0 and S[0, 0] > 0.0):  # no update through a degenerate S
                logw[i] = -np.inf
                continue
            Si = np.empty((2, 2))
            Si[0, 0], Si[0, 1] = S[1, 1] / det, -S[0, 1] / det
            Si[1, 0], Si[1, 1] = -S[1, 0] / det, S[0, 0] / det
            d2 = (
                nu[0] * nu[0] * Si[0, 0]
                + nu[0] * nu[1] * (Si[0, 1] + Si[1, 0])
                + nu[1] * nu[1] * Si[1, 1]
            )
            logw[i] = math.log(max(mu[t, i], 1e-300)) - 0.5 * (d2 + math.log(det))
            K = PHt @ Si
            KS = K @ S
            for a in range(4):
                xm[t, i, a] += K[a, 0] * nu[0] + K[a, 1] * nu[1]
            for a in range(4):
                for b in range(4):
                    Pm[t, i, a, b] -= KS[a, 0] * K[b, 0] + KS[a, 1] * K[b, 1]
            for a in range(4):
                for b in range(a + 1, 4):
                    m = 0.5 * (Pm[t, i, a, b] + Pm[t, i, b, a])
                    Pm[t, i, a, b] = m
                    Pm[t, i, b, a] = m
        top = max(logw[0], logw[1])
        if top == -np.inf:
            continue
        w0, w1 = math.exp(logw[0] - top), math.exp(logw[1] - top)
        p0, p1 = w0 / (w0 + w1), w1 / (w0 + w1)
        p0, p1 = max(p0, min_probability), max(p1, min_probability)
        mu[t, 0], mu[t, 1] = p0 / (p0 + p1), p1 / (p0 + p1)


@compiled
def floor_position(P: FloatArray, rows: IntArray, sigma_m: float) -> None:
    """Raise, in place, the eigenvalues of the (x, y) block of ``P[r]`` (n, n) for each
    ``r`` in ``rows`` to ``sigma_m²`` at least, by adding a positive semi-definite matrix
    (:func:`agent.tracking.filters.floor_position` is its numpy reference). For a
    symmetric 2 × 2 block ``M`` with eigenvalues ``λ₁ ≥ λ₂`` below ``s = σ²``: ``s·I − M``
    when both are, else ``(s − λ₂)·(λ₁I − M)/(λ₁ − λ₂)``."""
    s = sigma_m * sigma_m
    for r in rows:
        a, c = P[r, 0, 0], P[r, 1, 1]
        b = 0.5 * (P[r, 0, 1] + P[r, 1, 0])
        hi, lo = _eigenvalues_2x2(a, b, c)
        if lo >= s:
            continue
        if hi <= s:
            d00, d01, d11 = s - a, -b, s - c
        else:
            f = (s - lo) / (hi - lo)
            d00, d01, d11 = f * (hi - a), -f * b, f * (hi - c)
        P[r, 0, 0] += d00
        P[r, 0, 1] += d01
        P[r, 1, 0] += d01
        P[r, 1, 1] += d11


@compiled
def hit(
    t: IntArray,
    refl: FloatArray,
    stamp_ns: int,
    drift: FloatArray,
    hits: IntArray,
    updated: BoolArray,
    last_seen_ns: IntArray,
    refl_sum: FloatArray,
    refl_n: IntArray,
) -> None:
    """Mark tracks ``t`` updated at ``stamp_ns`` with features of reflectivity ``refl``
    (NaN: none measured): the drift since the last update cleared, the hit counted, the
    reflectivity summed."""
    for i in range(t.size):
        r = t[i]
        drift[r] = 0.0
        hits[r] += 1
        updated[r] = True
        last_seen_ns[r] = stamp_ns
        if math.isfinite(refl[i]):
            refl_sum[r] += refl[i]
            refl_n[r] += 1


@compiled
def feature_times(
    centre_xy: FloatArray,
    radius_m: FloatArray,
    points_xy: FloatArray,
    age_s: FloatArray,
    tolerance_m: float,
) -> tuple[FloatArray, FloatArray]:
    """``tau`` (k,) and ``var`` (k,): the mean and variance of the ages ``age_s`` (n,) of
    the points ``points_xy`` (n, 2) within ``tolerance_m`` of each circle (0 and 0 when
    none is; see :func:`agent.tracking.tracker.feature_times`). Two passes: the mean, then
    the spread about it."""
    k, n = centre_xy.shape[0], points_xy.shape[0]
    tau = np.zeros(k)
    var = np.zeros(k)
    member = np.empty(n, dtype=np.bool_)
    for f in range(k):
        cx, cy, r = centre_xy[f, 0], centre_xy[f, 1], radius_m[f]
        total, m = 0.0, 0
        for i in range(n):
            d = math.hypot(points_xy[i, 0] - cx, points_xy[i, 1] - cy)
            member[i] = abs(d - r) <= tolerance_m
            if member[i]:
                total += age_s[i]
                m += 1
        if m == 0:
            continue
        mean = total / m
        spread = 0.0
        for i in range(n):
            if member[i]:
                spread += (age_s[i] - mean) ** 2
        tau[f], var[f] = mean, spread / m
    return tau, var


@compiled
def cylinder_outputs(
    xm: FloatArray,
    Pm: FloatArray,
    mu: FloatArray,
    radius_m: FloatArray,
    radius_var: FloatArray,
    start: int,
    state: FloatArray,
    cov: FloatArray,
    params: FloatArray,
    pcov: FloatArray,
    extent: FloatArray,
    moving: FloatArray,
) -> None:
    """Fill rows ``start`` to ``start + k`` of the ``tracks`` arrays for ``k`` cylinder
    tracks: the IMM's moment-matched estimate (:func:`imm_combine`) as state and
    covariance; the parameters (x, y, radius) with the position's covariance and the
    radius's variance; the radius as extent; the CV model's probability as moving."""
    xc, Pc = imm_combine(xm, Pm, mu)
    for t in range(xm.shape[0]):
        o = start + t
        for a in range(4):
            state[o, a] = xc[t, a]
            for b in range(4):
                cov[o, a, b] = Pc[t, a, b]
        for a in range(3):
            for b in range(3):
                pcov[o, a, b] = Pc[t, a, b] if a < 2 and b < 2 else 0.0
        params[o, 0], params[o, 1], params[o, 2] = xc[t, 0], xc[t, 1], radius_m[t]
        pcov[o, 2, 2] = radius_var[t]
        extent[o, 0] = radius_m[t]
        moving[o] = min(max(mu[t, 1], 0.0), 1.0)


@compiled
def point_view_inputs(
    corner_x: FloatArray,
    corner_P: FloatArray,
    corner_confirmed: BoolArray,
    xm: FloatArray,
    Pm: FloatArray,
    mu: FloatArray,
    radius_m: FloatArray,
    mu_seen: FloatArray,
    cylinder_confirmed: BoolArray,
    pose: FloatArray,
    corner_footprint_m: float,
    corner_min_beams: int,
    cylinder_min_beams: int,
    moving_threshold: float,
    max_static_sigma_m: float,
    max_position_sigma_m: float,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, IntArray, BoolArray, BoolArray]:
    """What expected visibility needs of the point tracks, corners then cylinders (the
    IMM's moment-matched position, :func:`imm_combine`), and which are lost.

    Returns, per track: its position in ``base_link`` under ``pose``; its near surface's
    offset (a cylinder's radius, 0 for a corner); its angular footprint (the radius, or
    ``corner_footprint_m``); its position σ (√ of the (x, y) block's trace); the beams it
    needs; whether on each side (corners); and *lost*, its larger axis's σ above its bound
    (``max_static_sigma_m`` for confirmed static tracks, else ``max_position_sigma_m``;
    a cylinder is moving when ``mu_seen`` exceeds ``moving_threshold``).
    """
    nc, ny = corner_x.shape[0], xm.shape[0]
    n = nc + ny
    pts = np.empty((n, 2))
    radius = np.zeros(n)
    foot = np.empty(n)
    sigma = np.empty(n)
    beams = np.empty(n, dtype=np.int64)
    two_sided = np.zeros(n, dtype=np.bool_)
    lost = np.zeros(n, dtype=np.bool_)
    xc, Pc = imm_combine(xm, Pm, mu)
    c, s = math.cos(pose[2]), math.sin(pose[2])
    for i in range(n):
        if i < nc:
            x, y = corner_x[i, 0], corner_x[i, 1]
            pxx, pxy, pyy = corner_P[i, 0, 0], corner_P[i, 0, 1], corner_P[i, 1, 1]
            foot[i] = corner_footprint_m
            beams[i] = corner_min_beams
            two_sided[i] = True
            static_bound = corner_confirmed[i]
        else:
            t = i - nc
            x, y = xc[t, 0], xc[t, 1]
            pxx, pxy, pyy = Pc[t, 0, 0], Pc[t, 0, 1], Pc[t, 1, 1]
            radius[i] = foot[i] = radius_m[t]
            beams[i] = cylinder_min_beams
            static_bound = cylinder_confirmed[t] and not mu_seen[t] > moving_threshold
        dx, dy = x - pose[0], y - pose[1]
        pts[i, 0] = dx * c + dy * s
        pts[i, 1] = -dx * s + dy * c
        sigma[i] = math.sqrt(max(pxx + pyy, 0.0))
        major = math.sqrt(max(_eigenvalues_2x2(pxx, pxy, pyy)[0], 0.0))
        lost[i] = major > (max_static_sigma_m if static_bound else max_position_sigma_m)
    return pts, radius, foot, sigma, beams, two_sided, lost


@compiled
def keep_epochs(
    epoch_ns: IntArray,
    hyp: FloatArray,
    slip: FloatArray,
    count: int,
    live_a: IntArray,
    live_b: IntArray,
    stamp_ns: int,
    pose: FloatArray,
) -> int:
    """Compact, in place, the first ``count`` epochs (stamps ``epoch_ns``, drift state
    ``hyp`` (·, h, 3) and ``slip`` (·, 3, 3)) to those whose stamp some track's last update
    (``live_a``, ``live_b``) still holds, in order; then, if one holds ``stamp_ns``, start
    that epoch after them at ``pose`` (the caller leaves room for it). Returns the new
    count."""
    m = 0
    for i in range(count):
        e = epoch_ns[i]
        used = False
        for v in live_a:
            if v == e:
                used = True
                break
        if not used:
            for v in live_b:
                if v == e:
                    used = True
                    break
        if used:
            if m != i:
                epoch_ns[m] = e
                hyp[m] = hyp[i]
                slip[m] = slip[i]
            m += 1
    now = False
    for v in live_a:
        now = now or v == stamp_ns
    for v in live_b:
        now = now or v == stamp_ns
    if now:
        epoch_ns[m] = stamp_ns
        for j in range(hyp.shape[1]):
            hyp[m, j, 0], hyp[m, j, 1], hyp[m, j, 2] = pose[0], pose[1], pose[2]
        slip[m] = 0.0
        m += 1
    return m


@compiled
def assignment_rest(
    rows: IntArray, cols: IntArray, cost: FloatArray, gated: BoolArray, near: BoolArray
) -> tuple[IntArray, IntArray, IntArray, BoolArray, IntArray, BoolArray]:
    """What :func:`agent.tracking.tracker._assign` makes of an assignment ``rows`` (tracks)
    to ``cols`` (features) over ``cost`` (k, m): the pairs inside their gate; the features
    left unassigned; for each of those, whether some track gates it, the gating track of
    least cost (0 when none does), and whether it lies in some track's ``near`` gate."""
    k, m = cost.shape
    ok = np.zeros(rows.size, dtype=np.bool_)
    taken = np.zeros(m, dtype=np.bool_)
    for i in range(rows.size):
        if gated[rows[i], cols[i]]:
            ok[i] = True
            taken[cols[i]] = True
    free = np.flatnonzero(~taken)
    in_gate = np.zeros(free.size, dtype=np.bool_)
    best = np.zeros(free.size, dtype=np.int64)
    close = np.zeros(free.size, dtype=np.bool_)
    for n in range(free.size):
        f = free[n]
        least = np.inf
        for t in range(k):
            if gated[t, f]:
                in_gate[n] = True
                if cost[t, f] < least:
                    least = cost[t, f]
                    best[n] = t
            if near[t, f]:
                close[n] = True
    return rows[ok], cols[ok], free, in_gate, best, close


@compiled_inline
def _along_line(alpha: float, px: float, py: float) -> float:
    """The along-line coordinate of point (px, py) on a line of normal angle ``alpha``."""
    return -px * math.sin(alpha) + py * math.cos(alpha)


@compiled
def extents_near(x: FloatArray, ends: FloatArray, ends_m: FloatArray, gap_m: float) -> BoolArray:
    """(k, m): whether feature ``j``'s end points ``ends_m[j]`` (2, 2), taken along track
    ``t``'s line ``x[t]`` = (α, ρ), overlap the track's extent ``ends[t]`` or come within
    ``gap_m`` of it."""
    k, m = x.shape[0], ends_m.shape[0]
    out = np.zeros((k, m), dtype=np.bool_)
    for t in range(k):
        a = x[t, 0]
        u0 = _along_line(a, ends[t, 0, 0], ends[t, 0, 1])
        u1 = _along_line(a, ends[t, 1, 0], ends[t, 1, 1])
        lo, hi = min(u0, u1) - gap_m, max(u0, u1) + gap_m
        for j in range(m):
            v0 = _along_line(a, ends_m[j, 0, 0], ends_m[j, 0, 1])
            v1 = _along_line(a, ends_m[j, 1, 0], ends_m[j, 1, 1])
            out[t, j] = max(v0, v1) >= lo and min(v0, v1) <= hi
    return out


@compiled
def merge_extents(
    x: FloatArray,
    ends: FloatArray,
    seen: BoolArray,
    t: IntArray,
    ends_m: FloatArray,
    seen_m: BoolArray,
) -> None:
    """Grow, in place, the extent ``ends[t[i]]`` (end points on line ``x[t[i]]``, with
    ``seen``: whether each is a real end) by feature ``i``'s end points ``ends_m[i]`` (with
    ``seen_m[i]``); at an end the feature saw, the feature's end replaces the track's. In
    order: a track given twice takes both. Each extent is kept in along-line order."""
    for i in range(t.size):
        r = t[i]
        a, rho = x[r, 0], x[r, 1]
        u0 = _along_line(a, ends[r, 0, 0], ends[r, 0, 1])
        u1 = _along_line(a, ends[r, 1, 0], ends[r, 1, 1])
        s0, s1 = seen[r, 0], seen[r, 1]
        if u1 < u0:
            u0, u1, s0, s1 = u1, u0, s1, s0
        v0 = _along_line(a, ends_m[i, 0, 0], ends_m[i, 0, 1])
        v1 = _along_line(a, ends_m[i, 1, 0], ends_m[i, 1, 1])
        m0, m1 = seen_m[i, 0], seen_m[i, 1]
        if v1 < v0:
            v0, v1, m0, m1 = v1, v0, m1, m0
        lo = v0 if m0 else min(u0, v0)
        hi = v1 if m1 else max(u1, v1)
        hi = max(hi, lo)
        c, s = math.cos(a), math.sin(a)
        ends[r, 0, 0], ends[r, 0, 1] = rho * c - lo * s, rho * s + lo * c
        ends[r, 1, 0], ends[r, 1, 1] = rho * c - hi * s, rho * s + hi * c
        seen[r, 0] = m0 or (s0 and v0 >= u0)
        seen[r, 1] = m1 or (s1 and v1 <= u1)


@compiled
def new_segments(
    alpha: FloatArray, rho: FloatArray, ends_m: FloatArray, seen_m: BoolArray, rows: IntArray
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """For the features ``rows``: their lines (α, ρ), their end points projected on them in
    along-line order, and which of those ends were seen."""
    n = rows.size
    xs = np.empty((n, 2))
    ends = np.empty((n, 2, 2))
    seen = np.empty((n, 2), dtype=np.bool_)
    for i in range(n):
        j = rows[i]
        a, p = alpha[j], rho[j]
        xs[i, 0], xs[i, 1] = a, p
        u0 = _along_line(a, ends_m[j, 0, 0], ends_m[j, 0, 1])
        u1 = _along_line(a, ends_m[j, 1, 0], ends_m[j, 1, 1])
        s0, s1 = seen_m[j, 0], seen_m[j, 1]
        if u1 < u0:
            u0, u1, s0, s1 = u1, u0, s1, s0
        c, s = math.cos(a), math.sin(a)
        ends[i, 0, 0], ends[i, 0, 1] = p * c - u0 * s, p * s + u0 * c
        ends[i, 1, 0], ends[i, 1, 1] = p * c - u1 * s, p * s + u1 * c
        seen[i, 0], seen[i, 1] = s0, s1
    return xs, ends, seen


@compiled
def cylinder_costs(
    z: FloatArray,
    R: FloatArray,
    tau: FloatArray,
    smear_var: FloatArray,
    xm: FloatArray,
    Pm: FloatArray,
    accel_psd: float,
    radius_m: FloatArray,
    radius_var: FloatArray,
    track_radius_m: FloatArray,
    track_radius_var: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """:func:`point_costs_timed` of ``m`` features against the static model (no process
    noise) and the CV model (``accel_psd``) of ``k`` IMM tracks ``xm`` (k, 2, 4), ``Pm``
    (k, 2, 4, 4), each entry the lesser of the two, plus the radius's term: the squared
    difference of the feature's radius and the track's over the sum of their variances in
    ``d²`` (3 dof), and that plus its log in the cost."""
    d2s, costs = point_costs_timed(z, R, tau, smear_var, xm[:, 0], Pm[:, 0], 0.0)
    d2c, costc = point_costs_timed(z, R, tau, smear_var, xm[:, 1], Pm[:, 1], accel_psd)
    d2 = np.minimum(d2s, d2c)
    cost = np.minimum(costs, costc)
    for t in range(xm.shape[0]):
        for j in range(z.shape[0]):
            s = track_radius_var[t] + radius_var[j]
            q = (radius_m[j] - track_radius_m[t]) ** 2 / s
            d2[t, j] += q
            cost[t, j] += q + math.log(s)
    return d2, cost


@compiled
def new_cylinders(
    z: FloatArray,
    R: FloatArray,
    tau: FloatArray,
    rows: IntArray,
    static_velocity_var: float,
    initial_velocity_var: float,
    accel_psd: float,
) -> tuple[FloatArray, FloatArray]:
    """The IMM states (n, 2, 4) and covariances (n, 2, 4, 4) of new tracks from the
    features ``rows``: at the feature's position with its covariance, at rest; the static
    model's velocity σ² ``static_velocity_var``; the CV model started at the feature's own
    time ``tau`` before the stamp and predicted to it (see
    :meth:`agent.tracking.tracker.Tracker._cylinders_step`)."""
    n = rows.size
    x0 = np.zeros((n, 2, 4))
    P0 = np.zeros((n, 2, 4, 4))
    for i in range(n):
        j = rows[i]
        tn = tau[j]
        for mdl in range(2):
            x0[i, mdl, 0], x0[i, mdl, 1] = z[j, 0], z[j, 1]
            for a in range(2):
                for b in range(2):
                    P0[i, mdl, a, b] = R[j, a, b]
        P0[i, 0, 2, 2] = P0[i, 0, 3, 3] = static_velocity_var
        P0[i, 1, 2, 2] = P0[i, 1, 3, 3] = initial_velocity_var
        for ax in range(2):
            P0[i, 1, ax, ax] += tn**2 * initial_velocity_var + accel_psd * tn**3 / 3.0
            cross = tn * initial_velocity_var + accel_psd * tn**2 / 2.0
            P0[i, 1, ax, ax + 2] = P0[i, 1, ax + 2, ax] = cross
            P0[i, 1, ax + 2, ax + 2] += accel_psd * tn
    return x0, P0


@compiled
def fuse_radius(
    radius_m: FloatArray,
    radius_var: FloatArray,
    t: IntArray,
    measured_m: FloatArray,
    measured_var: FloatArray,
    floor_var: float,
) -> None:
    """Each track ``t[i]``'s radius, in place, fused with the measurement ``i`` (inverse-
    variance weights), its variance kept at ``floor_var`` at least."""
    for i in range(t.size):
        r = t[i]
        r0, v0, rz, rv = radius_m[r], radius_var[r], measured_m[i], measured_var[i]
        radius_m[r] = (r0 * rv + rz * v0) / (rv + v0)
        radius_var[r] = max(v0 * rv / (v0 + rv), floor_var)


@compiled
def add_line_drift(P: FloatArray, x: FloatArray, vehicle_xy: FloatArray, delta: FloatArray) -> None:
    """Add, in place, to each line track's ``P`` (k, 2, 2) the pose noise ``delta`` (3, 3)
    mapped to its (α, ρ) = ``x[t]``: :func:`agent.tracking.geometry.line_drift_noise`."""
    for t in range(x.shape[0]):
        c, s = math.cos(x[t, 0]), math.sin(x[t, 0])
        j = (c, s, -vehicle_xy[0] * s + vehicle_xy[1] * c)  # ρ's row; α's is (0, 0, 1)
        dj = np.zeros(3)  # delta · jᵀ
        for a in range(3):
            for b in range(3):
                dj[a] += delta[a, b] * j[b]
        P[t, 0, 0] += delta[2, 2]
        P[t, 0, 1] += dj[2]
        P[t, 1, 0] += dj[2]
        P[t, 1, 1] += j[0] * dj[0] + j[1] * dj[1] + j[2] * dj[2]


@compiled
def bound_speeds(xm: FloatArray, Pm: FloatArray, max_speed_m_s: float) -> int:
    """Bring each CV model (model 1 of ``xm`` (k, 2, 4)) faster than ``max_speed_m_s`` back
    to it along its direction of motion, its velocity covariance grown by the correction's
    outer product, in place; returns how many were."""
    n = 0
    for t in range(xm.shape[0]):
        vx, vy = xm[t, 1, 2], xm[t, 1, 3]
        speed = math.hypot(vx, vy)
        if not speed > max_speed_m_s:
            continue
        n += 1
        f = 1.0 - max_speed_m_s / speed
        dx, dy = vx * f, vy * f
        xm[t, 1, 2], xm[t, 1, 3] = vx - dx, vy - dy
        Pm[t, 1, 2, 2] += dx * dx
        Pm[t, 1, 2, 3] += dx * dy
        Pm[t, 1, 3, 2] += dy * dx
        Pm[t, 1, 3, 3] += dy * dy
    return n


@compiled
def common_outputs(
    confirmed: BoolArray,
    updated: BoolArray,
    refl_sum: FloatArray,
    refl_n: IntArray,
    tentative: int,
    coasting: int,
    confirmed_status: int,
) -> tuple[NDArray[np.uint8], FloatArray]:
    """Each track's status (tentative; confirmed, updated this scan; or coasting) and mean
    reflectivity (NaN before any)."""
    k = confirmed.size
    status = np.empty(k, dtype=np.uint8)
    refl = np.empty(k)
    for t in range(k):
        if not confirmed[t]:
            status[t] = tentative
        elif updated[t]:
            status[t] = confirmed_status
        else:
            status[t] = coasting
        refl[t] = refl_sum[t] / refl_n[t] if refl_n[t] > 0 else np.nan
    return status, refl
