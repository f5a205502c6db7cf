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
from typing import Any, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from agent.arrays import FloatArray
from agent.perception.features import sample_kernels
from agent.perception.features.model import IndexArray
from agent.perception.features.rows import CXX, CYY, ONE, X, Y


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


def _read_only(a: NDArray[Any]) -> NDArray[Any]:
    """``a``, or a read-only view of it: the compiled kernel then sees the arrays of a
    decoded message (read-only) whoever calls it, and has one signature, loaded by
    ``warm_up``, rather than one to compile for each mix of writable and read-only ones."""
    if a.flags.writeable:
        a = a.view()
        a.flags.writeable = False
    return a


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
    # One compiled pass picks, stacks and groups the samples. The spot at either end of a
    # run straddles the run's edge (the footprint and the detection filter span about a
    # sample), so its intensity is not the surface's alone: measured on planes, the run's
    # end samples are the ones whose intensity misfits the plane by 5-13 σ. Their
    # intensities are not fitted (their ranges are).
    ro = _read_only
    idx, rows, theta, bounds, pair_cov = sample_kernels.stacked_samples(
        ro(p), ro(c.reshape(n, 4)), ro(seg), ro(fl), ro(org), ro(th), ro(rng), ro(inten),
        signal_constant, baseline_m, math.nan if noise_current_A is None else noise_current_A,
        intensity_model_sigma, neighbour_correlation,
    )  # fmt: skip
    if idx.size == 0:
        return None
    runs = list(itertools.pairwise(bounds.tolist()))
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
