"""Scan windows, pan limits and the timing of one mirror sweep.

The mirror sweeps at a constant angular rate (40° in 100 ms), in both directions; the ADC
samples at a fixed 2.56 kHz, so a window narrower than ±20° is swept in proportionally less
time with proportionally fewer samples. Angles are radians in the head frame: θ = 0 along the
head's x axis, positive counter-clockwise (REP-103).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from agent.arrays import FloatArray
from agent.errors import HeadCommandError
from agent.sensor.params import SensorParameters

_ANGLE_SLACK_RAD = 1e-9  # forgive float round-off from degree conversions at the limits


@dataclass(frozen=True)
class ScanWindow:
    """A scan window ``[low_rad, high_rad]`` within the mirror's ±20°."""

    low_rad: float
    high_rad: float

    @classmethod
    def full(cls, params: SensorParameters) -> ScanWindow:
        """The whole ±20° field of view."""
        return cls(-params.scan_half_angle_rad, params.scan_half_angle_rad)

    @classmethod
    def from_degrees(cls, low_deg: float, high_deg: float) -> ScanWindow:
        return cls(math.radians(low_deg), math.radians(high_deg))

    @property
    def width_rad(self) -> float:
        return self.high_rad - self.low_rad

    def validate(self, params: SensorParameters) -> ScanWindow:
        """Return ``self`` if the head can scan it, else raise :class:`HeadCommandError`."""
        lim = params.scan_half_angle_rad
        lo, hi = self.low_rad, self.high_rad
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise HeadCommandError(f"scan window must be finite, got [{lo}, {hi}] rad")
        if lo < -lim - _ANGLE_SLACK_RAD or hi > lim + _ANGLE_SLACK_RAD:
            raise HeadCommandError(
                f"scan window [{math.degrees(lo):.2f}, {math.degrees(hi):.2f}] deg lies outside "
                f"the mirror's ±{math.degrees(lim):.0f} deg"
            )
        if hi - lo < params.sample_spacing_rad - _ANGLE_SLACK_RAD:
            raise HeadCommandError(
                f"scan window [{math.degrees(lo):.3f}, {math.degrees(hi):.3f}] deg is narrower "
                f"than one sample ({math.degrees(params.sample_spacing_rad):.3f} deg); "
                "low must be below high"
            )
        return self


def _within(angle_rad: float, limit_rad: float, what: str, whose: str) -> float:
    if not math.isfinite(angle_rad) or abs(angle_rad) > limit_rad + _ANGLE_SLACK_RAD:
        raise HeadCommandError(
            f"{what} {math.degrees(angle_rad):.2f} deg lies outside {whose} "
            f"±{math.degrees(limit_rad):.0f} deg"
        )
    return float(np.clip(angle_rad, -limit_rad, limit_rad))


def validate_scan_angle(scan_angle_rad: float, params: SensorParameters) -> float:
    """Return ``scan_angle_rad`` if the mirror can point there (±20°), else raise."""
    return _within(scan_angle_rad, params.scan_half_angle_rad, "scan angle", "the mirror's")


def validate_pan(pan_rad: float, params: SensorParameters) -> float:
    """Return ``pan_rad`` if within ±90°, else raise :class:`HeadCommandError`."""
    return _within(pan_rad, params.pan_limit_rad, "pan", "the head's")


@dataclass(frozen=True)
class SweepTiming:
    """When each sample of one sweep is taken and where the mirror points then.

    ``n`` samples, the k-th at ``start_time_s + (k + ½)/f_s`` with the mirror at
    ``first_angle + direction·(k + ½)·Δθ``; the sweep lasts ``n/f_s``.
    """

    n_samples: int
    direction: int  # +1 sweeping towards positive θ, -1 towards negative θ
    start_time_s: float
    start_angle_rad: float  # mirror angle at start_time_s
    rate_rad_s: float  # signed angular rate
    sample_rate_hz: float

    @property
    def duration_s(self) -> float:
        return self.n_samples / self.sample_rate_hz

    def angle_at(self, t: FloatArray) -> FloatArray:
        """Mirror angle at times ``t`` (the sweep's own straight line, extended both ways)."""
        return self.start_angle_rad + self.rate_rad_s * (np.asarray(t) - self.start_time_s)

    def sample_times(self) -> FloatArray:
        k = np.arange(self.n_samples, dtype=np.float64)
        return self.start_time_s + (k + 0.5) / self.sample_rate_hz


def sweep_timing(
    window: ScanWindow, direction: int, start_time_s: float, params: SensorParameters
) -> SweepTiming:
    """Timing of one sweep over ``window`` (validated) in ``direction`` (+1 or -1).

    The number of samples is the window width over the sample spacing, rounded; the swept arc
    is centred on the window.
    """
    window.validate(params)
    if direction not in (1, -1):
        raise HeadCommandError(f"sweep direction must be +1 or -1, got {direction}")
    n = max(1, round(window.width_rad / params.sample_spacing_rad))
    arc = n * params.sample_spacing_rad
    centre = 0.5 * (window.low_rad + window.high_rad)
    start = centre - direction * 0.5 * arc
    return SweepTiming(
        n_samples=n,
        direction=direction,
        start_time_s=start_time_s,
        start_angle_rad=start,
        rate_rad_s=direction * params.scan_rate_rad_s,
        sample_rate_hz=params.sample_rate_hz,
    )
