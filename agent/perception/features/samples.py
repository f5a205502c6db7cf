"""One scan's valid samples, stacked once as the columns of one matrix and grouped by run.

Everything downstream fits spans ``[start, stop)`` of these columns; :func:`per_span`
remembers a result per span for the scan.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
from numpy.typing import ArrayLike

from agent.arrays import FloatArray
from agent.perception.features import sample_kernels
from agent.perception.features.model import IndexArray
from agent.perception.features.rows import CXX, CYY, ONE, VARB, WINT, X, Y


@dataclass(frozen=True)
class Samples:
    """The valid samples, compressed and grouped by segment id (scan order within each).

    ``rows`` stacks, per sample: 1, x, y, C_xx, 2·C_xy, C_yy, the beam's origin (x, y) and
    unit direction (x, y), the variance along the beam, range, intensity, and the
    reflectivity it implies at normal incidence (I_s·r²/(S·cos θ), eq. 6.10-6.11; NaN
    where the intensity is not positive), the unit vector from the point to the
    detector's viewpoint (a baseline to the head's left of the centre of scanning, eq. 6.5):
    the surface's Lambertian factor is the cosine between its normal and this direction,
    and the weight ``1/σ²`` of the log intensity (``σ² = (I_n/I_s)² + σ_model²``; 0 where
    the intensity is unknown or not positive).
    Weighted moments and projected variances of any run are then single matrix products
    over a slice of ``xy1`` and ``cov3``.
    """

    index: IndexArray  # (m,) index into the scan's arrays
    rows: FloatArray  # (ROWS, m)
    theta: FloatArray  # (m,)
    runs: list[tuple[int, int]]  # [start, stop) of each segment id, in id order
    pair_cov: FloatArray  # (m − 1,) covariance of range errors of samples k and k + 1

    @property
    def xy1(self) -> FloatArray:
        return self.rows[ONE : Y + 1]

    @property
    def cov3(self) -> FloatArray:
        return self.rows[CXX : CYY + 1]

    def point(self, k: int) -> tuple[float, float]:
        return float(self.rows[X, k]), float(self.rows[Y, k])

    def cov2(self, k: int) -> FloatArray:
        cxx, cxy2, cyy = self.rows[CXX : CYY + 1, k].tolist()
        return np.array([[cxx, 0.5 * cxy2], [0.5 * cxy2, cyy]])

    def variance_along(self, k: int, c: float, s: float) -> float:
        """Sample k's variance along the unit vector (c, s)."""
        cxx, cxy2, cyy = self.rows[CXX : CYY + 1, k].tolist()
        return float(c * c * cxx + c * s * cxy2 + s * s * cyy)


def prepare_samples(
    points_xy: ArrayLike,
    covariance: ArrayLike,
    segment: ArrayLike,
    flag: ArrayLike,
    intensity_A: ArrayLike,
    range_m: ArrayLike,
    origin_xy: ArrayLike,
    beam_angle_rad: ArrayLike,
    signal_constant: float,
    baseline_m: float,
    noise_current_A: float | None,
    intensity_model_sigma: float,
    neighbour_correlation: float,
) -> Samples | None:
    """The valid samples of one scan, stacked, or None when none is usable (the arguments
    as for :func:`agent.perception.features.extraction.extract_features`).

    Raises ValueError when the arrays' shapes disagree.
    """
    p = np.asarray(points_xy, dtype=np.float64)
    c = np.asarray(covariance, dtype=np.float64)
    seg = np.asarray(segment)
    fl = np.asarray(flag)
    inten = np.asarray(intensity_A, dtype=np.float64)
    rng = np.asarray(range_m, dtype=np.float64)
    org = np.asarray(origin_xy, dtype=np.float64)
    th = np.asarray(beam_angle_rad, dtype=np.float64)
    if seg.ndim != 1:
        raise ValueError(f"segment must be one-dimensional, got shape {seg.shape}")
    n = seg.shape[0]
    for name, got, want in (
        ("points_xy", p.shape, (n, 2)),
        ("covariance", c.shape, (n, 2, 2)),
        ("flag", fl.shape, (n,)),
        ("intensity_A", inten.shape, (n,)),
        ("range_m", rng.shape, (n,)),
        ("origin_xy", org.shape, (n, 2)),
        ("beam_angle_rad", th.shape, (n,)),
    ):
        if got != want:
            raise ValueError(f"{name} has shape {got}, expected {want} (n = {n} samples)")
    if n == 0:
        return None
    idx = np.flatnonzero((fl == 0) & (seg >= 0))
    if idx.size == 0:
        return None
    theta = np.take(th, idx)
    rows, good = sample_kernels.sample_rows(
        np.take(p, idx, axis=0), np.take(c.reshape(n, 4), idx, axis=0),
        np.take(org, idx, axis=0), theta, np.take(rng, idx), np.take(inten, idx),
        signal_constant, baseline_m,
        math.nan if noise_current_A is None else noise_current_A, intensity_model_sigma,
    )  # fmt: skip
    if not good.all():
        keep = np.flatnonzero(good)
        if keep.size == 0:
            return None
        idx, rows, theta = idx[keep], rows[:, keep], theta[keep]
    seg_v = seg[idx]
    steps = np.diff(seg_v)
    if np.any(steps < 0):  # ids not in scan order: group them, keep scan order inside
        order = np.argsort(seg_v, kind="stable")
        idx, rows, theta = idx[order], rows[:, order], theta[order]
        steps = np.diff(seg[idx])
    cuts = (np.flatnonzero(steps) + 1).tolist()
    runs = list(itertools.pairwise([0, *cuts, idx.size]))
    # The spot at either end of a run straddles the run's edge (the footprint and the
    # detection filter span about a sample), so its intensity is not the surface's alone:
    # measured on planes, the run's end samples are the ones whose intensity misfits the
    # plane by 5-13 σ. Their intensities are not fitted (their ranges are).
    rows[WINT, [0, *cuts]] = 0.0
    rows[WINT, [c - 1 for c in cuts] + [idx.size - 1]] = 0.0
    # Range errors of neighbouring samples (consecutive in the scan) are correlated by the
    # detection filter: covariance ρ₁·σ_k·σ_{k+1} along the beams.
    sigma_b = np.sqrt(rows[VARB])
    neighbours = np.diff(idx) == 1
    pair_cov = np.where(neighbours, neighbour_correlation * sigma_b[:-1] * sigma_b[1:], 0.0)
    rows = np.ascontiguousarray(rows)
    return Samples(index=idx, rows=rows, theta=theta, runs=runs, pair_cov=pair_cov)


_Owner = TypeVar("_Owner")
_Result = TypeVar("_Result")


def per_span(
    method: Callable[[_Owner, int, int], _Result],
) -> Callable[[_Owner, int, int], _Result]:
    """Remember a method's result per span (start, stop) on its instance (one scan's)."""
    slot = f"_per_span_{method.__name__}"

    @functools.wraps(method)
    def remembered(self: _Owner, start: int, stop: int) -> _Result:
        memo: dict[tuple[int, int], _Result] = vars(self).setdefault(slot, {})
        key = (start, stop)
        if key not in memo:
            memo[key] = method(self, start, stop)
        return memo[key]

    return remembered
