"""Array type aliases shared by every package (shapes and units are stated where they are
used), :func:`shifted`, the move of a grid that follows the vehicle,
:func:`largest_sigma`, the worst-axis standard deviation of 2 × 2 covariances, and
:func:`wrap_angle`."""

from __future__ import annotations

import math
from typing import TypeAlias

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray: TypeAlias = NDArray[np.float64]
BoolArray: TypeAlias = NDArray[np.bool_]


def shifted(grid: FloatArray, rows: int, cols: int) -> FloatArray:
    """``grid`` moved by whole cells, for a grid re-centred on the vehicle: new[i, j] =
    old[i + rows, j + cols], −inf (never) where nothing was, all −inf when the shift is the
    grid's size or more."""
    out = np.full_like(grid, -np.inf)
    n_r, n_c = grid.shape
    src_r = slice(max(rows, 0), n_r + min(rows, 0))
    dst_r = slice(max(-rows, 0), n_r + min(-rows, 0))
    src_c = slice(max(cols, 0), n_c + min(cols, 0))
    dst_c = slice(max(-cols, 0), n_c + min(-cols, 0))
    if abs(rows) < n_r and abs(cols) < n_c:
        out[dst_r, dst_c] = grid[src_r, src_c]
    return out


def largest_sigma(P: FloatArray) -> FloatArray:
    """√ of the larger eigenvalue of symmetric 2 × 2 blocks ``(k, 2, 2)``, (k,)."""
    a, c = P[:, 0, 0], P[:, 1, 1]
    b = 0.5 * (P[:, 0, 1] + P[:, 1, 0])
    lam = 0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b * b)
    return np.asarray(np.sqrt(np.maximum(lam, 0.0)), dtype=np.float64)


def wrap_angle(angle: ArrayLike) -> FloatArray:
    """Angles (rad) wrapped to [−π, π), same shape."""
    a = np.asarray(angle, dtype=np.float64)
    return np.asarray((a + math.pi) % math.tau - math.pi, dtype=np.float64)
