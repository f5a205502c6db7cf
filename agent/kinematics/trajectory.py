"""Vehicle poses over time, for placing each sample of a scan taken while driving.

A trajectory maps an array of times to arrays of planar poses ``(x_m, y_m, yaw_rad)`` in the
world frame (REP-103). The head's centre of scanning is mounted ``mount_offset_m`` ahead of
the vehicle's base origin; pan rotates the head about it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

from agent.arrays import FloatArray


class Trajectory(Protocol):
    def poses_at(self, t: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Poses ``(x, y, yaw)``, each shaped like ``t``."""
        ...


@dataclass(frozen=True)
class StaticPose:
    """A vehicle standing still."""

    x_m: float = 0.0
    y_m: float = 0.0
    yaw_rad: float = 0.0

    def poses_at(self, t: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        shape = np.shape(t)
        return (np.full(shape, self.x_m), np.full(shape, self.y_m), np.full(shape, self.yaw_rad))


@dataclass(frozen=True)
class ConstantTwist:
    """A unicycle moving at constant speed and yaw rate from a pose at ``t0_s``.

    Exact integration: a straight line when the yaw rate is zero, a circular arc otherwise.
    """

    x_m: float
    y_m: float
    yaw_rad: float
    speed_m_s: float
    yaw_rate_rad_s: float
    t0_s: float = 0.0

    def poses_at(self, t: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        dt = np.asarray(t, dtype=np.float64) - self.t0_s
        w, v = self.yaw_rate_rad_s, self.speed_m_s
        yaw = self.yaw_rad + w * dt
        if abs(w) < 1e-12:
            x = self.x_m + v * dt * math.cos(self.yaw_rad)
            y = self.y_m + v * dt * math.sin(self.yaw_rad)
        else:
            x = self.x_m + v / w * (np.sin(yaw) - math.sin(self.yaw_rad))
            y = self.y_m - v / w * (np.cos(yaw) - math.cos(self.yaw_rad))
        return x, y, yaw


def head_origin(x: FloatArray, y: FloatArray, yaw: FloatArray, mount_offset_m: float) -> FloatArray:
    """World position ``(n, 2)`` of the centre of scanning for vehicle poses ``(x, y, yaw)``."""
    return np.stack([x + mount_offset_m * np.cos(yaw), y + mount_offset_m * np.sin(yaw)], axis=-1)
