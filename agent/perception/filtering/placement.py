"""Motion compensation: the samples placed in the vehicle frame at the scan's end.

Each sample is placed with the vehicle pose at its own time, interpolated from the
vehicle-state stream, and expressed in the vehicle frame at the scan's reference time (its
last sample). Each point's covariance combines the range σ along the beam and the
scan-angle repeatability across it.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from agent.arrays import FloatArray
from agent.kinematics.trajectory import Trajectory
from agent.perception.filtering import placement_kernels


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
    points, cov, origin, heading = placement_kernels.place_points(
        x, y, yaw, beam, np.array(range_m, dtype=np.float64), np.array(sigma_m, dtype=np.float64),
        float(scan_angle_sigma_rad), reference, float(mount_offset_m),
    )  # fmt: skip
    return PlacedPoints(points, cov, origin, heading)
