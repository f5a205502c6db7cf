"""The generalised optimal sub-pattern assignment (GOSPA) metric over point objects.

Rahmathullah, García-Fernández and Svensson, "Generalized optimal sub-pattern assignment
metric", FUSION 2017, eq. (1) with α = 2: for true points ``X`` and estimates ``Y``,

    d(X, Y) = ( min over assignments γ of  Σ_(i,j)∈γ d(x_i, y_j)^p
                + c^p/2 · (|X| − |γ|) + c^p/2 · (|Y| − |γ|) )^(1/p)

over assignments γ of pairs each at distance below ``c``. With α = 2 the metric splits into
a localisation part (the assigned pairs' distances), a missed part (``c^p/2`` per true point
left unassigned) and a false part (``c^p/2`` per estimate left unassigned); the parts are
reported to the power ``p`` (summable), the total as the metric itself. With p = 1 the
total is the sum of the parts.

The optimal assignment is found by :func:`scipy.optimize.linear_sum_assignment` on the cost
``min(d, c)^p``: a pair at ``c`` or beyond costs as much as leaving both unassigned (two
halves of ``c^p``), so the optimum never needs such a pair, and any that it picks is split.

Points may carry a *kind* (an integer class): a pair of different kinds is never assigned
(as if their distance were beyond ``c``); this is still a metric (the base distance
``d'`` = ``d`` for equal kinds, ``c`` otherwise, is one on the labelled points when capped
at ``c``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from agent.arrays import FloatArray

__all__ = ["GospaResult", "assign", "gospa"]

IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True)
class GospaResult:
    """One GOSPA evaluation.

    Attributes
    ----------
    distance
        The metric, metres (with p = 1; metres to the power 1 in general).
    localisation, missed, false
        Its parts, each to the power ``p`` (they sum to ``distance**p``).
    pairs
        (q, 2) int64: (truth index, estimate index) of the assigned pairs.
    pair_distance_m
        (q,) their distances, metres.
    """

    distance: float
    localisation: float
    missed: float
    false: float
    pairs: IntArray
    pair_distance_m: FloatArray


def assign(
    truth_xy: npt.ArrayLike,
    estimate_xy: npt.ArrayLike,
    c: float,
    truth_kind: npt.ArrayLike | None = None,
    estimate_kind: npt.ArrayLike | None = None,
) -> tuple[IntArray, FloatArray]:
    """The assignment of least total ``min(d, c)`` cost, keeping only pairs nearer than ``c``.

    Parameters
    ----------
    truth_xy, estimate_xy
        (n, 2) and (m, 2) points, metres.
    c
        The cut-off, metres, > 0.
    truth_kind, estimate_kind
        Optional (n,) and (m,) integer kinds; pairs of different kinds are never assigned.

    Returns
    -------
    pairs, distance_m
        (q, 2) int64 (truth index, estimate index) and (q,) their distances, ``d < c``.
    """
    if not c > 0.0:
        raise ValueError(f"c must be > 0, got {c!r}")
    x = np.asarray(truth_xy, dtype=np.float64).reshape(-1, 2)
    y = np.asarray(estimate_xy, dtype=np.float64).reshape(-1, 2)
    if x.shape[0] == 0 or y.shape[0] == 0:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    d = np.hypot(x[:, None, 0] - y[None, :, 0], x[:, None, 1] - y[None, :, 1])
    d = np.where(np.isfinite(d), d, np.inf)
    if truth_kind is not None or estimate_kind is not None:
        if truth_kind is None or estimate_kind is None:
            raise ValueError("give both truth_kind and estimate_kind, or neither")
        tk = np.asarray(truth_kind).reshape(-1)
        ek = np.asarray(estimate_kind).reshape(-1)
        if tk.shape[0] != x.shape[0] or ek.shape[0] != y.shape[0]:
            raise ValueError("kinds must have one entry per point")
        d = np.where(tk[:, None] == ek[None, :], d, np.inf)
    rows, cols = linear_sum_assignment(np.minimum(d, c))
    keep = d[rows, cols] < c
    pairs = np.stack([rows[keep], cols[keep]], axis=1).astype(np.int64)
    return pairs, np.asarray(d[rows[keep], cols[keep]], dtype=np.float64)


def gospa(
    truth_xy: npt.ArrayLike,
    estimate_xy: npt.ArrayLike,
    c: float = 0.5,
    p: float = 1.0,
    alpha: float = 2.0,
    truth_kind: npt.ArrayLike | None = None,
    estimate_kind: npt.ArrayLike | None = None,
) -> GospaResult:
    """GOSPA between true points and estimates (module docstring); ``alpha`` must be 2 (the
    only value with the localisation/missed/false split)."""
    if alpha != 2.0:
        raise ValueError(f"only alpha = 2 is supported, got {alpha!r}")
    if not p >= 1.0:
        raise ValueError(f"p must be >= 1, got {p!r}")
    x = np.asarray(truth_xy, dtype=np.float64).reshape(-1, 2)
    y = np.asarray(estimate_xy, dtype=np.float64).reshape(-1, 2)
    pairs, dist = assign(x, y, c, truth_kind, estimate_kind)
    localisation = float(np.sum(dist**p))
    missed = 0.5 * c**p * (x.shape[0] - pairs.shape[0])
    false = 0.5 * c**p * (y.shape[0] - pairs.shape[0])
    total = (localisation + missed + false) ** (1.0 / p)
    return GospaResult(total, localisation, missed, false, pairs, dist)
