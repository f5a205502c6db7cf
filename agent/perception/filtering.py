"""Filtering: validation gates, segmentation at range discontinuities, motion compensation.

Every sample leaves with a :class:`SampleFlag` saying why it was kept or dropped.

1. **Validation gates** (per sample): a position reading must exist; the signal must stand
   ``min_snr`` times above the noise current (σ_u = I_n/I_s, eq. 6.14: a noise-only sample
   in a missing part fails here); the range must lie in the depth of field.
2. **Segmentation** (along the scan line, the chapter's suggestion of a scan-line Kalman
   filter with an intensity validation gate). A Kalman filter on range along the scan with a
   constant-slope model and each sample's own variance is, over a short memory, a weighted
   linear prediction; here it runs over the whole scan (compiled,
   :mod:`agent.perception.kernels`), in
   both directions: each valid sample is predicted from the ``window`` valid samples before
   it and from the ``window`` after it, and tested with the exact innovation variance (χ², 1
   dof). Between two neighbours the scan breaks when the left sample disagrees with the
   prediction from the right *and* the right one with the prediction from the left, when the
   range changes faster than any surface seen at ``max_incidence_deg`` could, or when the
   range-corrected intensity jumps by more than ``intensity_ratio_gate`` (the intensity
   validation gate: intensity changes smoothly along one surface, and blended samples
   between two surfaces show it). Runs shorter than ``min_run`` samples are transition
   samples: ``MIXED`` when their ranges lie between the surfaces on either side (the
   footprint and the detection filter blend the two surfaces' currents into phantom ranges),
   ``ISOLATED`` otherwise.
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
from numpy.typing import NDArray

from agent.arrays import FloatArray
from agent.kinematics.trajectory import Trajectory
from agent.perception import kernels


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
    corrected = intensity_A[idx] * r**2  # intensity with the 1/r² of eq. 6.10 taken out
    slope_per_step = settings.sample_spacing_rad * math.tan(
        math.radians(settings.max_incidence_deg)
    )
    breaks = kernels.scan_breaks(
        r, var, corrected, np.diff(idx), settings.window, settings.gate_chi2,
        slope_per_step, settings.intensity_ratio_gate, settings.max_gap,
    )  # fmt: skip
    runs, code = kernels.label_runs(
        r, breaks, settings.min_run, SampleFlag.MIXED.value, SampleFlag.ISOLATED.value
    )
    segment[idx] = runs
    dropped = np.flatnonzero(code)
    if dropped.size:
        flags[idx[dropped]] = code[dropped]
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
    _table: FloatArray | None = field(default=None, repr=False)  # the states, yaw unwrapped

    def _states_table(self) -> FloatArray:
        """(k, 6) array of the states (t, x, y, yaw, speed, yaw rate), yaw unwrapped; built
        once per change of the history (a scan asks for its samples' poses and then for its
        reference pose)."""
        if self._table is None:
            table = np.array(self._states, dtype=np.float64)
            table[:, 3] = np.unwrap(table[:, 3])
            self._table = table
        return self._table

    def add(self, t: float, x: float, y: float, yaw: float, speed: float, yaw_rate: float) -> None:
        if self._states and t <= self._states[-1][0]:
            if t < self._states[-1][0]:
                return  # out of order: keep the newer
            self._states.pop()
        self._states.append((t, x, y, yaw, speed, yaw_rate))
        self._table = None
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
        s = self._states_table()
        ts, xs, ys, yaws = s[:, 0], s[:, 1], s[:, 2], s[:, 3]
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
    reference = np.array([a[0] for a in poses.poses_at(np.array([reference_time_s]))])
    # (Fresh float64 arrays: the message's may be read-only, a second compiled signature.)
    beam = np.add(pan_rad, scan_angle_rad, dtype=np.float64)
    points, cov, origin, heading = kernels.place_points(
        x, y, yaw, beam, np.array(range_m, dtype=np.float64), np.array(sigma_m, dtype=np.float64),
        float(scan_angle_sigma_rad), reference, float(mount_offset_m),
    )  # fmt: skip
    return PlacedPoints(points, cov, origin, heading)
