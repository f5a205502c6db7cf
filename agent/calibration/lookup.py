"""The calibration's bilinear look-up, both tables at once (:meth:`Calibration.lookup`).

Written in numpy, not compiled: the calibration process does not load numba, whose import
alone costs it about half a second at every restart. A scan's look-up is then a few dozen
numpy calls over a few hundred samples, and each call costs about a microsecond whatever
its size, several when the caches are cold (as they are between scans at 10 Hz): the
look-up is laid out for few calls. Both axes' indices are computed as one ``(2, n)`` array,
and the four corners of both tables come from one ``take`` on the two tables stacked.

The arithmetic is the textbook bilinear formula in its usual order of operations,
``(1−a)(1−b)·T₀₀ + (1−a)b·T₀₁ + a(1−b)·T₁₀ + ab·T₁₁``, so the results are those of the
formula written out per table, to the last bit.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from agent.arrays import BoolArray, FloatArray


class BilinearTables:
    """Two tables on one regular grid, for :meth:`interpolate`.

    Parameters
    ----------
    rows_grid : (nθ,) regular, ascending (the scan angles, rad).
    columns_grid : (nu,) regular, ascending (the normalised image positions).
    first, second : (nθ, nu) the tables (``1/r`` and ``∂(1/r)/∂u``), NaN where unknown.
    rows_slack : how far beyond its ends, in grid steps, the first axis still counts as
        inside (and takes the end values); the second axis allows rounding only.
    """

    def __init__(
        self,
        rows_grid: FloatArray,
        columns_grid: FloatArray,
        first: FloatArray,
        second: FloatArray,
        rows_slack: float,
    ) -> None:
        n_rows, n_cols = rows_grid.size, columns_grid.size
        self._origin = np.array([[rows_grid[0]], [columns_grid[0]]])
        self._step = np.array([[rows_grid[1] - rows_grid[0]], [columns_grid[1] - columns_grid[0]]])
        self._lowest = np.array([[-rows_slack], [-1e-9]])
        self._highest = np.array([[n_rows - 1 + rows_slack], [n_cols - 1 + 1e-9]])
        self._last_node = np.array([[n_rows - 1.0], [n_cols - 1.0]])
        self._last_cell = np.array([[n_rows - 2], [n_cols - 2]], dtype=np.intp)
        self._columns = n_cols
        self._tables = np.stack([first.ravel(), second.ravel()])  # (2, nθ·nu)
        # Node (i, j) + these: T[i, j], T[i, j+1], T[i+1, j], T[i+1, j+1].
        self._corners = np.array([[0], [1], [n_cols], [n_cols + 1]], dtype=np.intp)

    def interpolate(
        self, row_at: FloatArray, column_at: FloatArray
    ) -> tuple[FloatArray, BoolArray]:
        """Both tables at the points (``row_at``, ``column_at``), each (n,), grid units.

        Returns ``(values, inside)``: ``values`` (2, n), the first table's then the
        second's (meaningless where not ``inside``); ``inside`` (n,) whether the point lies
        on the grid (within the slack). NaN and infinite coordinates are outside.
        """
        n = row_at.size
        f = np.empty((2, n))
        np.subtract(row_at, self._origin[0], out=f[0])
        np.subtract(column_at, self._origin[1], out=f[1])
        f /= self._step  # fractional node indices
        ok = f >= self._lowest
        ok &= f <= self._highest
        inside = ok[0] & ok[1]
        # Clamped onto the grid; fmax maps NaN to the low end (its nodes, never used).
        np.fmax(f, 0.0, out=f)
        np.fmin(f, self._last_node, out=f)
        node: NDArray[np.intp] = f.astype(np.intp)
        np.minimum(node, self._last_cell, out=node)  # the last node: 1 into the last cell
        frac = np.empty((2, 2, n))  # (1 − a, 1 − b), then (a, b)
        np.subtract(f, node, out=frac[1])
        np.subtract(1.0, frac[1], out=frac[0])
        # weight[p, q] = (1−a, a)[p] · (1−b, b)[q]: the four corners' weights in order.
        weight = frac[:, None, 0] * frac[None, :, 1]
        flat = node[0] * self._columns
        flat += node[1]
        corners = np.take(self._tables, flat + self._corners, axis=1)  # (2, 4, n)
        corners *= weight.reshape(4, n)
        values = corners[:, 0] + corners[:, 1]
        values += corners[:, 2]
        values += corners[:, 3]
        return values, inside
