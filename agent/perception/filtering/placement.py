"""Motion compensation: the samples placed in the vehicle frame at the scan's end.

Each sample is placed with the vehicle pose at its own time, interpolated from the
vehicle-state stream, and expressed in the vehicle frame at the scan's reference time (its
last sample). Each point's covariance combines the range σ along the beam and the
scan-angle repeatability across it.

**State age.** A sample's state age is the time from the vehicle state its pose is reckoned
from to the sample's time: since the newest state at or before it, or, before the first state
held, until that first state. A scan's is the largest over its samples and its reference
time. Only stamps and the samples' own times enter it, never a clock, so live, replayed and
lock-step runs agree. Past the stage's ``max_state_age_s`` (the stream stopped, paused, left
a gap, or has not reached the scan yet), motion compensation is **off** for the whole scan,
as when no state has arrived: every sample is placed as if the vehicle had stood still at the
reference pose, i.e. in ``base_link`` at the scan's end with no motion model, and
:attr:`PlacedPoints.motion_compensated` is false. Within the limit the pose is interpolated
between states and extrapolated past either end with that end state's speed and yaw rate.
One flag per scan, so all or none of its samples are compensated.

**Order.** Only a state newer than the newest held is taken. An older one is dropped and
counted (:attr:`PoseHistory.out_of_order`), and so is a second state with the newest stamp
(:attr:`PoseHistory.duplicates`; the first is kept). Dropped rather than inserted: the bus
keeps one publisher's messages in order, so an older stamp means a fault (a clock stepped
back, a second publisher in another ``odom``), and inserting such states would splice another
timeline into the past and bend scans unnoticed; dropped, they leave the history to age
until compensation turns off, counted. A genuinely late state would add little anyway: its
newer neighbours bracket its time.

**Pose covariance: not used.** ``VehicleState.pose_covariance`` is the covariance of the
odometry pose in ``odom``: the drift accumulated since the start, growing without bound (or
shrinking when the controller fuses a fix). Placement needs the uncertainty of the motion
*between* a sample and the scan's end, at most one sweep (0.1 s): the covariance of a pose
difference, which two absolute covariances do not give without their cross-covariance, and
the message carries none. Its size: at the simulated platform's limits (0.5 m/s, 1.5 rad/s)
a sweep covers 5 cm and 0.15 rad; odometry good to 2 % of the motion leaves at most 1 mm and
3 mrad (1σ) at the scan's first sample and nothing at its last. Along the beam 1 mm is below
the samples' own range σ beyond about 0.9 m (0.1 mm at 0.5 m, 1.8 mm at 1 m, 9 mm at 1.5 m,
3 cm at 2 m). Across it, r × 3 mrad (≤ 7.5 mm at 2.5 m) exceeds the scan-angle repeatability
(0.1 mrad × r) in the fastest turns, but it is one slow rotation shared by neighbouring
samples, not independent noise: added to each point's covariance, a line fit would average
it away over hundreds of points. It is a heading error of the scan as a whole (≈ 1.5 mrad
on average at 1.5 rad/s), left to the stage that predicts features with the vehicle's motion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from agent.arrays import FloatArray
from agent.kinematics.trajectory import Trajectory
from agent.perception.filtering import placement_kernels

_COLUMNS = 6  # t (s), x (m), y (m), yaw (rad, unwrapped), speed (m/s), yaw rate (rad/s)


@dataclass(eq=False)
class PoseHistory:
    """Recent vehicle poses (odometry frame) for placing samples at their own times.

    Between two states the pose is interpolated (x, y linearly, yaw along the shorter way);
    past the last one (before the first) it is extrapolated with that state's speed and yaw
    rate. States older than ``seconds`` before the newest are forgotten. A state not newer
    than the newest held is dropped and counted (module docstring: why).
    """

    seconds: float = 3.0
    out_of_order: int = field(default=0, init=False)  # dropped: older than the newest held
    duplicates: int = field(default=0, init=False)  # dropped: the newest held's stamp again
    # The states as rows [start, end) of a growing buffer, yaw unwrapped as they arrive: a
    # scan reads them as an array view, with nothing to rebuild after each new state.
    _buffer: FloatArray = field(
        default_factory=lambda: np.empty((64, _COLUMNS)), init=False, repr=False
    )
    _start: int = field(default=0, init=False, repr=False)
    _end: int = field(default=0, init=False, repr=False)

    def _states(self) -> FloatArray:
        """(k, 6) view of the states held (columns as ``_COLUMNS``), oldest first."""
        return self._buffer[self._start : self._end]

    def add(self, t: float, x: float, y: float, yaw: float, speed: float, yaw_rate: float) -> None:
        """Take the state at stamp ``t`` (s) unless it is not newer than the newest held."""
        if self._end > self._start:
            newest = self._buffer[self._end - 1]
            if t <= newest[0]:
                if t < newest[0]:
                    self.out_of_order += 1
                else:
                    self.duplicates += 1
                return
            yaw = float(newest[3]) + math.remainder(yaw - float(newest[3]), math.tau)
        if self._end == len(self._buffer):
            held = self._states().copy()
            if len(held) * 2 > len(self._buffer):
                self._buffer = np.empty((2 * len(self._buffer), _COLUMNS))
            self._buffer[: len(held)] = held
            self._start, self._end = 0, len(held)
        self._buffer[self._end] = (t, x, y, yaw, speed, yaw_rate)
        self._end += 1
        while t - self._buffer[self._start, 0] > self.seconds:
            self._start += 1

    def __len__(self) -> int:
        return self._end - self._start

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

    def poses_and_age_at(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, float]:
        """Poses (x, y, yaw; m, m, rad, ``odom``) at times ``t`` (s), each (n,), and the largest
        state age over them (s; module docstring): identity and inf if no state has arrived.

        No limit on extrapolation here: :func:`place_samples` turns compensation off past
        the state age it is given.
        """
        t = np.asarray(t, dtype=np.float64)
        if not len(self):
            z = np.zeros(t.shape)
            return z, z.copy(), z.copy(), math.inf
        return placement_kernels.poses_and_age(self._states(), t)

    def poses_at(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Poses (x, y, yaw) at times ``t`` (see :meth:`poses_and_age_at`)."""
        x, y, yaw, _ = self.poses_and_age_at(t)
        return x, y, yaw

    def state_age_s(self, t: FloatArray) -> float:
        """The largest state age over times ``t`` (see :meth:`poses_and_age_at`)."""
        return self.poses_and_age_at(t)[3]


@dataclass(frozen=True)
class PlacedPoints:
    """Samples placed in the vehicle frame at the reference time."""

    points_xy: FloatArray  # (n, 2)
    covariance: FloatArray  # (n, 2, 2)
    origin_xy: FloatArray  # (n, 2) centre of scanning of each beam
    beam_heading_rad: FloatArray  # (n,) beam direction in the vehicle frame at reference time
    motion_compensated: bool = True  # false: placed with the reference pose alone, no motion
    state_age_s: float = 0.0  # the scan's largest state age (inf: no state had arrived)


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
    max_state_age_s: float = math.inf,
) -> PlacedPoints:
    """Points and covariances in the vehicle frame at ``reference_time_s`` (motion-compensated).

    Each sample's beam leaves the centre of scanning where the vehicle was at the sample's
    own time. Covariance: ``σ_r²`` along the beam, ``(r·σ_θ)²`` across it. When the state
    age of a sample or of ``reference_time_s`` exceeds ``max_state_age_s`` (s), or no state
    has arrived, compensation is off: every sample is placed with the reference
    pose (in ``base_link`` at ``reference_time_s``, no motion model) and
    ``motion_compensated`` is false (module docstring).
    """
    time_s = np.asarray(time_s, dtype=np.float64)
    times = np.append(time_s, reference_time_s)  # one pass for the samples and the reference
    x_all, y_all, yaw_all, age = poses.poses_and_age_at(times)
    compensated = len(poses) > 0 and age <= max_state_age_s
    if compensated:
        x, y, yaw = x_all[:-1], y_all[:-1], yaw_all[:-1]
        reference = np.array([x_all[-1], y_all[-1], yaw_all[-1]])
    else:  # every sample at the reference pose: the identity relative to it
        x = y = yaw = np.zeros(time_s.shape)
        reference = np.zeros(3)
    # (Fresh float64 arrays: the message's may be read-only, a second compiled signature.)
    beam = np.add(pan_rad, scan_angle_rad, dtype=np.float64)
    points, cov, origin, heading = placement_kernels.place_points(
        x, y, yaw, beam, np.array(range_m, dtype=np.float64), np.array(sigma_m, dtype=np.float64),
        float(scan_angle_sigma_rad), reference, float(mount_offset_m),
    )  # fmt: skip
    return PlacedPoints(points, cov, origin, heading, compensated, age)
