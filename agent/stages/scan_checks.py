"""What a stage checks of a ``filtered_scan`` before it uses one, beyond the schema.

The schema bounds each field alone; a scan can still say what no filtering stage would: a
valid sample (flag 0) with no point, range or σ, or with a covariance that is not a
covariance (not finite, not symmetric, or not positive semi-definite: a negative variance
along some direction, whose square root is NaN downstream). Such a scan comes from a broken
or hostile sender: the stages that read it (features; the planner, which does not read the
covariances) count it and drop it whole, as they do any malformed input.
"""

from __future__ import annotations

import numpy as np

from agent.runtime.messages import FilteredScan

__all__ = ["filtered_scan_problem"]

_SYMMETRY = 1e-9  # relative: what a float round trip leaves of a symmetric matrix


def filtered_scan_problem(scan: FilteredScan, covariance: bool = True) -> str | None:
    """Why ``scan`` cannot be used (a short reason, for logs), or None when it can;
    ``covariance`` False for a reader that does not use the samples' covariances."""
    n = scan.flag.shape[0]
    shapes = (scan.points_xy.shape, scan.covariance.shape, scan.origin_xy.shape,
              scan.range_m.shape, scan.sigma_m.shape, scan.scan_angle_rad.shape,
              scan.segment.shape, scan.intensity_A.shape)  # fmt: skip
    if shapes != ((n, 2), (n, 2, 2), (n, 2), (n,), (n,), (n,), (n,), (n,)) or (
        scan.beam_rad.size not in (0, n)
    ):
        return "inconsistent shapes"
    valid = scan.flag == 0
    if not np.isfinite(scan.origin_xy).all():
        return "an origin not finite"
    if not (
        np.isfinite(scan.points_xy[valid]).all()
        and np.isfinite(scan.range_m[valid]).all()
        and np.isfinite(scan.sigma_m[valid]).all()
    ):
        return "a valid sample without a finite point, range or sigma"
    if not covariance:
        return None
    c = scan.covariance[valid]
    if not np.isfinite(c).all():
        return "a valid sample's covariance not finite"
    a, b, b2, d = c[:, 0, 0], c[:, 0, 1], c[:, 1, 0], c[:, 1, 1]
    with np.errstate(over="ignore", invalid="ignore"):  # absurd sizes fail the tests below
        scale = np.maximum(np.abs(a) + np.abs(d), 1e-300)
        if not np.all(np.abs(b - b2) <= _SYMMETRY * scale):
            return "a covariance not symmetric"
        psd = (a >= 0.0) & (d >= 0.0) & (a * d - b * b >= -_SYMMETRY * scale**2)
    if not psd.all():
        return "a covariance not positive semi-definite (or beyond any size)"
    return None
