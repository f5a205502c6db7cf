"""The vehicle's odometry poses and their covariances over the last few seconds.

The tracker needs the pose, and its covariance, at each scan's reference time. Between two
states both are interpolated linearly (yaw the shorter way); past the newest state the pose
is extrapolated with its speed and yaw rate and the covariance held. The *state age* of a
time is as in :mod:`agent.perception.filtering.placement`: the time since the newest state at
or before it, or until the first state when it is earlier than all. Only a state newer than
the newest held is taken (the others are counted): one publisher keeps its order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from agent.arrays import FloatArray


@dataclass(frozen=True)
class PoseSample:
    """The vehicle at one time: pose (x, y, yaw; m, m, rad in ``odom``), its (3, 3)
    covariance and the state age it was reckoned with (s)."""

    pose: FloatArray
    covariance: FloatArray
    age_s: float


@dataclass(eq=False)
class PoseCovarianceHistory:
    """Recent (t, pose, covariance, speed, yaw rate) states, oldest first."""

    seconds: float = 3.0
    out_of_order: int = field(default=0, init=False)
    duplicates: int = field(default=0, init=False)
    _t: list[float] = field(default_factory=list, init=False, repr=False)
    _pose: list[FloatArray] = field(default_factory=list, init=False, repr=False)
    _cov: list[FloatArray] = field(default_factory=list, init=False, repr=False)
    _twist: list[tuple[float, float]] = field(default_factory=list, init=False, repr=False)

    def __len__(self) -> int:
        return len(self._t)

    def add(
        self,
        t_s: float,
        pose: FloatArray,
        covariance: FloatArray,
        speed_m_s: float = 0.0,
        yaw_rate_rad_s: float = 0.0,
    ) -> None:
        """Take the state at ``t_s`` unless it is not newer than the newest held."""
        pose = np.array(pose, dtype=np.float64)
        if self._t:
            if t_s <= self._t[-1]:
                if t_s < self._t[-1]:
                    self.out_of_order += 1
                else:
                    self.duplicates += 1
                return
            last_yaw = float(self._pose[-1][2])
            pose[2] = last_yaw + math.remainder(float(pose[2]) - last_yaw, math.tau)
        self._t.append(t_s)
        self._pose.append(pose)
        self._cov.append(np.array(covariance, dtype=np.float64))
        self._twist.append((speed_m_s, yaw_rate_rad_s))
        while len(self._t) > 2 and t_s - self._t[1] > self.seconds:
            del self._t[0], self._pose[0], self._cov[0], self._twist[0]

    def at(self, t_s: float) -> PoseSample | None:
        """The pose and covariance at ``t_s``; None if no state has arrived."""
        if not self._t:
            return None
        ts = self._t
        if t_s >= ts[-1]:
            dt = t_s - ts[-1]
            x, y, yaw = (float(v) for v in self._pose[-1])
            v, w = self._twist[-1]
            # Extrapolate along the arc's chord at the mid-heading (exact for a straight line).
            mid = yaw + 0.5 * w * dt
            pose = np.array([x + v * dt * math.cos(mid), y + v * dt * math.sin(mid), yaw + w * dt])
            return PoseSample(pose, self._cov[-1].copy(), dt)
        if t_s < ts[0]:
            return PoseSample(self._pose[0].copy(), self._cov[0].copy(), ts[0] - t_s)
        i = int(np.searchsorted(ts, t_s, side="right")) - 1
        f = (t_s - ts[i]) / (ts[i + 1] - ts[i])
        pose = (1.0 - f) * self._pose[i] + f * self._pose[i + 1]
        cov = (1.0 - f) * self._cov[i] + f * self._cov[i + 1]
        return PoseSample(pose, cov, t_s - ts[i])
