"""Array type aliases shared by every package (shapes and units are stated where they are
used), and :func:`shifted`, the move of a grid that follows the vehicle."""

from __future__ import annotations

from typing import TypeAlias

import numpy as np
from numpy.typing import NDArray

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
