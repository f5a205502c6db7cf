"""The vehicle: a differential-drive base, its outline, where the head sits, and its limits.

One definition for the simulator (collisions, motion), the vehicle controller (planning) and
scoring. Frames follow REP-103: ``base_link`` has x forward, y left, its origin at the centre
of the rectangular outline; metres, seconds, radians.

The defaults are a small differential-drive vehicle like the chapter's Robosoft platform:
0.8 m × 0.6 m, at most 0.5 m/s. The head's pan axis (the centre of scanning) is 0.30 m ahead
of the origin on the x axis (:attr:`agent.sensor.params.SensorParams.mount_offset_m`).
Acceleration limits are a modelling choice for a vehicle of about 50 kg with modest motors:
0.5 m/s² (stopping from full speed in 1 s over 0.25 m) and 2 rad/s² of yaw.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["VehicleSpec"]


@dataclass(frozen=True)
class VehicleSpec:
    """The vehicle's outline, head mount and motion limits.

    Attributes
    ----------
    length_m, width_m
        The outline, a rectangle centred on ``base_link``'s origin, length along x.
    head_offset_m
        The centre of scanning, this far ahead of the origin on the x axis.
    max_speed_m_s, max_yaw_rate_rad_s
        Speed (forward or back) and yaw rate limits.
    max_accel_m_s2, max_yaw_accel_rad_s2
        Limits on the change of speed and of yaw rate (braking included).
    moving_speed_m_s
        Faster than this at contact, the vehicle counts as moving (the collision is the
        vehicle's); slower, a mover that touches it ran into a stopped vehicle.
    """

    length_m: float = 0.8
    width_m: float = 0.6
    head_offset_m: float = 0.30
    max_speed_m_s: float = 0.5
    max_yaw_rate_rad_s: float = 1.5
    max_accel_m_s2: float = 0.5
    max_yaw_accel_rad_s2: float = 2.0
    moving_speed_m_s: float = 0.05

    def __post_init__(self) -> None:
        for name in (
            "length_m", "width_m", "max_speed_m_s", "max_yaw_rate_rad_s", "max_accel_m_s2",
            "max_yaw_accel_rad_s2", "moving_speed_m_s",
        ):  # fmt: skip
            value = float(getattr(self, name))
            if not math.isfinite(value) or value <= 0.0:
                raise ValueError(f"VehicleSpec.{name} must be positive and finite, got {value!r}")
        if not math.isfinite(self.head_offset_m):
            raise ValueError("VehicleSpec.head_offset_m must be finite")

    @property
    def circumradius_m(self) -> float:
        """The radius of the smallest circle about the origin that holds the outline."""
        return math.hypot(0.5 * self.length_m, 0.5 * self.width_m)

    @property
    def inradius_m(self) -> float:
        """Half the outline's smaller side: a disc about the origin inside the outline."""
        return 0.5 * min(self.length_m, self.width_m)

    def stopping_distance_m(self, speed_m_s: float) -> float:
        """Distance to stop from ``speed_m_s`` braking at ``max_accel_m_s2``."""
        return speed_m_s * speed_m_s / (2.0 * self.max_accel_m_s2)
