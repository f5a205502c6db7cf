"""Per-sample scan records passed between the head, calibration and the stages after it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from agent.arrays import FloatArray


class RawSamples(Protocol):
    """What calibration needs of a raw scan: :class:`RawScan` or the ``raw_scan`` message."""

    @property
    def time_s(self) -> FloatArray: ...
    @property
    def mirror_angle_rad(self) -> FloatArray: ...
    @property
    def pan_rad(self) -> FloatArray: ...
    @property
    def current_1_A(self) -> FloatArray: ...
    @property
    def current_2_A(self) -> FloatArray: ...
    @property
    def direction(self) -> int: ...


@dataclass(frozen=True)
class RawScan:
    """One sweep (or stare) as the head reports it: the input of calibration.

    Attributes
    ----------
    time_s : (n,) ADC sample times, s.
    mirror_angle_rad : (n,) scan angle read from the mirror at each sample time (with the
        mirror's 0.1 mrad repeatability), head frame.
    pan_rad : (n,) head pan angle at each sample, vehicle frame.
    current_1_A, current_2_A : (n,) synchronously detected, filtered electrode currents, A.
    direction : +1 or -1 for a sweep towards positive or negative θ; 0 for a stare.
    """

    time_s: FloatArray
    mirror_angle_rad: FloatArray
    pan_rad: FloatArray
    current_1_A: FloatArray
    current_2_A: FloatArray
    direction: int

    def __len__(self) -> int:
        return int(self.time_s.size)


@dataclass(frozen=True)
class CalibratedScan:
    """Calibrated samples of one sweep: the output of the calibration stage.

    Times and angles are those the measurements refer to: the ADC time and mirror angle moved
    back by the detection filter's group delay.

    Attributes
    ----------
    time_s : (n,) s. scan_angle_rad : (n,) head frame. pan_rad : (n,) vehicle frame.
    image_position_norm : (n,) LEP reading in [-1, 1]; NaN where there is no reading.
    intensity_A : (n,) signal current ``I_s = I1 + I2`` (may be ≤ 0 for noise-only samples).
    range_m : (n,) beam range from the centre of scanning; NaN where there is no reading or the
        reading lies outside the calibrated table.
    sigma_m : (n,) predicted standard deviation of ``range_m``; NaN where ``range_m`` is.
    direction : sweep direction (+1, -1) or 0 for a stare.
    """

    time_s: FloatArray
    scan_angle_rad: FloatArray
    pan_rad: FloatArray
    image_position_norm: FloatArray
    intensity_A: FloatArray
    range_m: FloatArray
    sigma_m: FloatArray
    direction: int
