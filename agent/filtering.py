"""Filtering: validation gates, segmentation at range discontinuities, motion compensation.

Every sample leaves with a :class:`SampleFlag` saying why it was kept or dropped.

1. **Validation gates** (per sample): a position reading must exist; the signal must stand
   ``min_snr`` times above the noise current (σ_u = I_n/I_s, eq. 6.14: a noise-only sample
   in a missing part fails here); the range must lie in the depth of field.
2. **Segmentation** (along the scan line, the chapter's suggestion of a scan-line Kalman
   filter with an intensity validation gate). A Kalman filter on range along the scan with a
   constant-slope model and each sample's own variance is, over a short memory, a weighted
   linear prediction; here it runs vectorised over the whole scan, in both directions: each
   valid sample is predicted from the ``window`` valid samples before it and from the
   ``window`` after it, and tested with the exact innovation variance (χ², 1 dof). Between
   two neighbours the scan breaks when the left sample disagrees with the prediction from
   the right *and* the right one with the prediction from the left, when the range changes
   faster than any surface seen at ``max_incidence_deg`` could, or when the range-corrected
   intensity jumps by more than ``intensity_ratio_gate`` (the intensity validation gate:
   intensity changes smoothly along one surface, and blended samples between two surfaces
   show it). Runs shorter than ``min_run`` samples are transition samples: ``MIXED`` when
   their ranges lie between the surfaces on either side (the footprint and the detection
   filter blend the two surfaces' currents into phantom ranges), ``ISOLATED`` otherwise.
3. **Motion compensation**: each sample is placed with the vehicle pose at its own time,
   interpolated from the vehicle-state stream, and expressed in the vehicle frame at the
   scan's reference time (its last sample). Each point's covariance combines the range σ
   along the beam and the scan-angle repeatability across it.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray

from agent.geometry import FloatArray
from agent.motion import Trajectory


class SampleFlag(IntEnum):
    """Why a sample was kept or dropped."""

    VALID = 0
    NO_READING = 1  # no position reading: nothing in range, off the detector, no signal
    LOW_SNR = 2  # signal too weak for its range to be trusted (missing parts: noise only)
    OUT_OF_RANGE = 3  # outside the depth of field
    MIXED = 4  # between two surfaces at a range discontinuity (a phantom range)
    ISOLATED = 5  # too few consistent neighbours to belong to a surface


@dataclass(frozen=True)
class FilterSettings:
    """The filter's gates.

    min_snr : signal over noise current, I_s/I_n (20: σ of position ≤ 5 % of the detector).
    depth_of_field_m : accepted beam ranges.
    gate_chi2 : innovation gate, χ² with 1 dof (16: 4σ, a false break in 16,000 samples).
    window : samples on each side used to predict a sample.
    max_incidence_deg : steepest surface accepted; range may change per sample by at most
        ``r·Δθ·tan(max_incidence)``.
    intensity_ratio_gate : largest change of range-corrected intensity between neighbours
        on one surface.
    max_gap : dropped samples a surface may span without a break.
    min_run : shortest run of samples accepted as a surface.
    """

    min_snr: float = 20.0
    depth_of_field_m: tuple[float, float] = (0.4, 2.5)
    gate_chi2: float = 16.0
    window: int = 4
    max_incidence_deg: float = 85.0
    intensity_ratio_gate: float = 1.3
    max_gap: int = 2
    min_run: int = 3
    sample_spacing_rad: float = math.radians(40.0) / 256


# ------------------------------------------------------------------------------------ gates
def validation_gates(
    range_m: FloatArray, intensity_A: FloatArray, noise_current_A: float, settings: FilterSettings
) -> NDArray[np.uint8]:
    """Per-sample flags from the gates alone (VALID, NO_READING, LOW_SNR, OUT_OF_RANGE)."""
    flags = np.full(range_m.shape, SampleFlag.VALID, dtype=np.uint8)
    near, far = settings.depth_of_field_m
    with np.errstate(invalid="ignore"):
        out = (range_m < near) | (range_m > far)
        weak = intensity_A < settings.min_snr * noise_current_A
    flags[out] = SampleFlag.OUT_OF_RANGE
    flags[weak] = SampleFlag.LOW_SNR
    flags[~np.isfinite(range_m)] = SampleFlag.NO_READING
    return flags


# ----------------------------------------------------------------------------- segmentation
def _linear_predictions(
    r: FloatArray, var: FloatArray, window: int
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Weighted straight-line predictions of each sample from its neighbours on either side.

    Returns ``(forward, forward_var, backward, backward_var)``: sample k predicted from
    samples k-window..k-1 and from k+1..k+window (NaN where there are not enough), each with
    the variance of the intercept of the weighted fit. Works on a compressed array of valid
    samples, index as the abscissa. Both directions use the same windows, so their weighted
    sums come from one product of the windows with the abscissae's powers.
    """
    n = r.size
    fwd, fvar, bwd, bvar = np.full((4, n), np.nan)
    if n <= window:
        return fwd, fvar, bwd, bvar
    w = 1.0 / var
    windows = sliding_window_view(np.stack([w, w * r]), window, axis=1)  # (2, n-window+1, window)
    j = np.arange(window, dtype=np.float64)
    xf, xb = j - window, j + 1.0  # abscissae seen from the sample predicted, before and after
    sums = windows @ np.stack([np.ones(window), xf, xf * xf, xb, xb * xb], axis=1)
    sw, sy = sums[0, :, 0], sums[1, :, 0]
    sx, sxx, sxy = sums[0, :, 1::2].T, sums[0, :, 2::2].T, sums[1, :, 1::2].T  # (2, windows)
    det = sw * sxx - sx * sx
    pred = (sxx * sy - sx * sxy) / det  # the intercepts, at x = 0
    pvar = sxx / det
    # Window s predicts sample s + window forward and sample s - 1 backward.
    fwd[window:], fvar[window:] = pred[0, :-1], pvar[0, :-1]
    bwd[: n - window], bvar[: n - window] = pred[1, 1:], pvar[1, 1:]
    return fwd, fvar, bwd, bvar


def segment_scan(
    range_m: FloatArray,
    sigma_m: FloatArray,
    intensity_A: FloatArray,
    flags: NDArray[np.uint8],
    settings: FilterSettings,
) -> tuple[NDArray[np.uint8], NDArray[np.int32]]:
    """Break the scan at discontinuities; flag transition samples. Returns (flags, segment).

    ``segment`` numbers the surviving runs 0, 1, ... in scan order, -1 for dropped samples.
    """
    flags = flags.copy()
    segment = np.full(range_m.shape, -1, dtype=np.int32)
    idx = np.flatnonzero(flags == SampleFlag.VALID)
    if idx.size == 0:
        return flags, segment
    r = range_m[idx]
    var = sigma_m[idx] ** 2
    w = settings.window
    fwd, fvar, bwd, bvar = _linear_predictions(r, var, w)
    with np.errstate(invalid="ignore"):
        fwd_bad = (r - fwd) ** 2 / (var + fvar) > settings.gate_chi2
        bwd_bad = (r - bwd) ** 2 / (var + bvar) > settings.gate_chi2
    # Between compressed neighbours j-1 and j:
    disagree = fwd_bad[1:] & bwd_bad[:-1]
    # A missing prediction (near the ends, or after a break) cannot disagree.
    step = np.diff(r)
    slope_limit = (
        np.minimum(r[1:], r[:-1])
        * settings.sample_spacing_rad
        * np.diff(idx)
        * math.tan(math.radians(settings.max_incidence_deg))
    )
    noise = 5.0 * np.sqrt(var[1:] + var[:-1])
    too_steep = np.abs(step) > slope_limit + noise
    corrected = intensity_A[idx] * r**2  # intensity with the 1/r² of eq. 6.10 taken out
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = corrected[1:] / corrected[:-1]
    jump = ~(
        (ratio < settings.intensity_ratio_gate) & (ratio > 1.0 / settings.intensity_ratio_gate)
    )
    gap = np.diff(idx) > settings.max_gap + 1
    breaks = disagree | too_steep | jump | gap
    run = np.concatenate([[0], np.cumsum(breaks)])
    counts = np.bincount(run)
    short = counts[run] < settings.min_run
    if np.any(short):
        # Transition samples: MIXED when between the neighbouring runs' ranges.
        starts = np.concatenate([[0], np.flatnonzero(breaks) + 1])
        ends = np.concatenate([np.flatnonzero(breaks), [r.size - 1]])
        prev_r = np.where(starts > 0, r[np.maximum(starts - 1, 0)], np.nan)[run]
        next_r = np.where(ends < r.size - 1, r[np.minimum(ends + 1, r.size - 1)], np.nan)[run]
        lo, hi = np.fmin(prev_r, next_r), np.fmax(prev_r, next_r)
        between = (r > lo) & (r < hi)
        flags[idx[short & between]] = SampleFlag.MIXED
        flags[idx[short & ~between]] = SampleFlag.ISOLATED
    keep = ~short
    if np.any(keep):
        _, dense = np.unique(run[keep], return_inverse=True)
        segment[idx[keep]] = dense.astype(np.int32)
    return flags, segment


def gate_and_segment(
    range_m: FloatArray,
    sigma_m: FloatArray,
    intensity_A: FloatArray,
    noise_current_A: float,
    settings: FilterSettings,
) -> tuple[NDArray[np.uint8], NDArray[np.int32]]:
    """The validation gates, then segmentation: per-sample ``(flags, segment)``."""
    flags = validation_gates(range_m, intensity_A, noise_current_A, settings)
    return segment_scan(range_m, sigma_m, intensity_A, flags, settings)


# ---------------------------------------------------------------------- motion compensation
@dataclass
class PoseHistory:
    """Recent vehicle poses (odometry frame) for placing samples at their own times.

    Between two states the pose is interpolated (x, y linearly, yaw along the shorter way);
    after the last one it is extrapolated with that state's speed and yaw rate; before the
    first it is held.
    """

    seconds: float = 3.0
    _states: deque[tuple[float, float, float, float, float, float]] = field(default_factory=deque)

    def add(self, t: float, x: float, y: float, yaw: float, speed: float, yaw_rate: float) -> None:
        if self._states and t <= self._states[-1][0]:
            if t < self._states[-1][0]:
                return  # out of order: keep the newer
            self._states.pop()
        self._states.append((t, x, y, yaw, speed, yaw_rate))
        while self._states and t - self._states[0][0] > self.seconds:
            self._states.popleft()

    def __len__(self) -> int:
        return len(self._states)

    @classmethod
    def sampled(
        cls, trajectory: Trajectory, t0_s: float, t1_s: float, rate_hz: float = 50.0
    ) -> PoseHistory:
        """A history of ``trajectory`` sampled at ``rate_hz`` (as a vehicle state stream)."""
        history = cls(seconds=max(3.0, t1_s - t0_s + 1.0))
        times = np.arange(t0_s, t1_s, 1.0 / rate_hz)
        x, y, yaw = trajectory.poses_at(times)
        speed = float(getattr(trajectory, "speed_m_s", 0.0))
        yaw_rate = float(getattr(trajectory, "yaw_rate_rad_s", 0.0))
        for t, xi, yi, heading in zip(times, x, y, yaw, strict=True):
            history.add(float(t), float(xi), float(yi), float(heading), speed, yaw_rate)
        return history

    def poses_at(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Poses (x, y, yaw) at times ``t``; identity if no state has arrived."""
        t = np.asarray(t, dtype=np.float64)
        if not self._states:
            z = np.zeros(t.shape)
            return z, z.copy(), z.copy()
        s = np.array(self._states)
        ts, xs, ys = s[:, 0], s[:, 1], s[:, 2]
        yaws = np.unwrap(s[:, 3])
        x = np.interp(t, ts, xs)
        y = np.interp(t, ts, ys)
        yaw = np.interp(t, ts, yaws)
        after = t > ts[-1]
        if np.any(after):
            dt = t[after] - ts[-1]
            v, w, yaw0 = s[-1, 4], s[-1, 5], yaws[-1]
            yaw_a = yaw0 + w * dt
            if abs(w) < 1e-9:
                xa = xs[-1] + v * dt * math.cos(yaw0)
                ya = ys[-1] + v * dt * math.sin(yaw0)
            else:
                xa = xs[-1] + v / w * (np.sin(yaw_a) - math.sin(yaw0))
                ya = ys[-1] - v / w * (np.cos(yaw_a) - math.cos(yaw0))
            x[after], y[after], yaw[after] = xa, ya, yaw_a
        return x, y, yaw


@dataclass(frozen=True)
class PlacedPoints:
    """Samples placed in the vehicle frame at the reference time."""

    points_xy: FloatArray  # (n, 2)
    covariance: FloatArray  # (n, 2, 2)
    origin_xy: FloatArray  # (n, 2) centre of scanning of each beam
    beam_heading_rad: FloatArray  # (n,) beam direction in the vehicle frame at reference time


def place_samples(
    time_s: FloatArray,
    scan_angle_rad: FloatArray,
    pan_rad: FloatArray,
    range_m: FloatArray,
    sigma_m: FloatArray,
    scan_angle_sigma_rad: float,
    poses: PoseHistory,
    reference_time_s: float,
    mount_offset_m: float,
) -> PlacedPoints:
    """Points and covariances in the vehicle frame at ``reference_time_s`` (motion-compensated).

    Each sample's beam leaves the centre of scanning where the vehicle was at the sample's
    own time. Covariance: ``σ_r²`` along the beam, ``(r·σ_θ)²`` across it.
    """
    x, y, yaw = poses.poses_at(time_s)
    rx, ry, ryaw = (float(a[0]) for a in poses.poses_at(np.array([reference_time_s])))
    heading_odom = yaw + pan_rad + scan_angle_rad
    ox = x + mount_offset_m * np.cos(yaw)
    oy = y + mount_offset_m * np.sin(yaw)
    px = ox + range_m * np.cos(heading_odom)
    py = oy + range_m * np.sin(heading_odom)
    c, s = math.cos(ryaw), math.sin(ryaw)

    def to_vehicle(ax: FloatArray, ay: FloatArray) -> FloatArray:
        dx, dy = ax - rx, ay - ry
        return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)

    heading = heading_odom - ryaw
    along = np.stack([np.cos(heading), np.sin(heading)], axis=-1)
    across = np.stack([-np.sin(heading), np.cos(heading)], axis=-1)
    var_along = sigma_m**2
    var_across = (range_m * scan_angle_sigma_rad) ** 2
    cov = (var_along[:, None, None] * along[:, :, None] * along[:, None, :]
           + var_across[:, None, None] * across[:, :, None] * across[:, None, :])  # fmt: skip
    return PlacedPoints(to_vehicle(px, py), cov, to_vehicle(ox, oy), heading)
