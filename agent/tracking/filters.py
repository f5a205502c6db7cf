"""Batched Kalman-filter steps over ``k`` tracks at once, and the static/constant-velocity IMM.

Shapes lead with the track axis: states ``(k, n)``, covariances ``(k, n, n)``; the IMM's carry
a model axis after it, ``(k, 2, n)``. Measurements are of the first two state components
(``H = [I₂ 0]``): a point's position, or a line's (α, ρ).
"""

from __future__ import annotations

import numpy as np

from agent.arrays import FloatArray

LOG_2PI = float(np.log(2.0 * np.pi))


def inverse_2x2(S: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Inverses and determinants of ``(..., 2, 2)`` matrices, in closed form."""
    a, b, c, d = S[..., 0, 0], S[..., 0, 1], S[..., 1, 0], S[..., 1, 1]
    det = a * d - b * c
    inv = np.empty_like(S)
    inv[..., 0, 0] = d / det
    inv[..., 0, 1] = -b / det
    inv[..., 1, 0] = -c / det
    inv[..., 1, 1] = a / det
    return inv, det


def mahalanobis_2(nu: FloatArray, S_inv: FloatArray) -> FloatArray:
    """``νᵀ·S⁻¹·ν`` over ``(..., 2)`` innovations and ``(..., 2, 2)`` inverse covariances."""
    n0, n1 = nu[..., 0], nu[..., 1]
    return np.asarray(
        n0 * n0 * S_inv[..., 0, 0]
        + n0 * n1 * (S_inv[..., 0, 1] + S_inv[..., 1, 0])
        + n1 * n1 * S_inv[..., 1, 1],
        dtype=np.float64,
    )


def update_first_two(
    x: FloatArray, P: FloatArray, nu: FloatArray, R: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Kalman update of states ``(..., n)`` with innovations ``ν (..., 2)`` of their first two
    components and measurement covariances ``R (..., 2, 2)``.

    Returns the updated ``x``, ``P`` (``P − K·S·Kᵀ``, symmetrised), the innovation
    covariances' inverses and determinants (for likelihoods).
    """
    S = P[..., :2, :2] + R
    S_inv, det = inverse_2x2(S)
    K = P[..., :, :2] @ S_inv
    x = x + (K @ nu[..., None])[..., 0]
    P = P - K @ S @ np.swapaxes(K, -1, -2)
    P = 0.5 * (P + np.swapaxes(P, -1, -2))
    return x, P, S_inv, det


def log_likelihood_2(nu: FloatArray, S_inv: FloatArray, det: FloatArray) -> FloatArray:
    """Gaussian log-density of 2-D innovations."""
    return np.asarray(-0.5 * (mahalanobis_2(nu, S_inv) + np.log(det)) - LOG_2PI, dtype=np.float64)


def cv_transition(dt_s: float) -> FloatArray:
    """(4, 4) constant-velocity transition over (x, y, vx, vy)."""
    F = np.eye(4)
    F[0, 2] = F[1, 3] = dt_s
    return F


def cv_process_noise(dt_s: float, accel_psd: float) -> FloatArray:
    """(4, 4) continuous white-acceleration noise ``q`` (m²/s³) over ``dt_s``."""
    q = accel_psd
    a, b, c = q * dt_s**3 / 3.0, q * dt_s**2 / 2.0, q * dt_s
    return np.array([[a, 0, b, 0], [0, a, 0, b], [b, 0, c, 0], [0, b, 0, c]], dtype=np.float64)


def static_transition() -> FloatArray:
    """(4, 4) the static model: the position stays, the velocity is zero."""
    return np.diag([1.0, 1.0, 0.0, 0.0])


def imm_mix(
    x: FloatArray, P: FloatArray, mu: FloatArray, Pi: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The IMM's mixing step.

    ``x (k, 2, 4)``, ``P (k, 2, 4, 4)``, model probabilities ``mu (k, 2)``, switching
    matrix ``Pi (2, 2)`` (``Pi[i, j]``: from model i to j over the step). Returns the mixed
    initial conditions of each model and the predicted model probabilities ``c (k, 2)``.
    """
    c = mu @ Pi
    w = mu[:, :, None] * Pi[None, :, :] / np.maximum(c[:, None, :], 1e-300)  # w[k, i, j]
    x0 = np.einsum("kij,kin->kjn", w, x)
    dx = x[:, :, None, :] - x0[:, None, :, :]  # (k, i, j, n)
    spread = dx[..., :, None] * dx[..., None, :]
    P0 = (w[..., None, None] * (P[:, :, None] + spread)).sum(axis=1)
    return x0, P0, c


def imm_combine(x: FloatArray, P: FloatArray, mu: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Moment-matched estimate ``(k, 4)``, ``(k, 4, 4)`` of the IMM's models."""
    xc = (mu[:, :, None] * x).sum(axis=1)
    dx = x - xc[:, None, :]
    Pc = (mu[:, :, None, None] * (P + dx[..., :, None] * dx[..., None, :])).sum(axis=1)
    return xc, Pc


def floor_position(P: FloatArray, sigma_m: float) -> FloatArray:
    """(k, n, n) covariances with their (x, y) block's eigenvalues raised to ``sigma_m²``
    at least (a positive semi-definite matrix added: the rest is left as it is)."""
    w, v = np.linalg.eigh(P[:, :2, :2])
    add = np.clip(sigma_m**2 - w, 0.0, None)
    out = P.copy()
    out[:, :2, :2] += (v * add[:, None, :]) @ v.transpose(0, 2, 1)
    return out
