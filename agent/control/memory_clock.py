"""The free-space memory's clock: seconds the vehicle has spent moving.

What the controller remembers of static space goes stale for one reason: the odometry that
placed it drifts, and wheel odometry drifts only while the wheels turn
(:mod:`agent.sim.odometry`: scale, track and slip errors all grow with the distance a wheel
rolls). A vehicle that stands still (waiting for a walker to pass, looking with its head)
loses nothing of what it knew about the walls round it; forgetting on the wall clock left
it, after 30 s of waiting, not knowing the ring beside its own outline, which the sensor
cannot see from where it stands (nearer than the near limit, or behind the window), so it
could not turn or move off until it had backed and looked again. So the memory's ages are
read on this clock, which runs only while the vehicle moves. (Measured as an ablation, the
memory never forgotten, on the 39 parks among ``evaluate``'s random runs 0-95 of seed 0,
``active``, perfect odometry, no walkers: 5 → 8 done.)

:class:`MovingClock` keeps the clock's reading as a piecewise-linear function of the graph
clock (a breakpoint at each start and stop) and inverts it: :meth:`MovingClock.since` is the
earliest graph time from which no more than a given span of moving has passed.
"""

from __future__ import annotations

import bisect
import math
import sys

import numpy as np

from agent.arrays import FloatArray

__all__ = ["DriftClock", "MovingClock"]


class MovingClock:
    """Seconds spent moving, on the graph clock's times (module docstring)."""

    def __init__(self) -> None:
        self._t: list[float] = []  # graph times of the breakpoints (starts and stops)
        self._m: list[float] = []  # the clock's reading at each
        self._moving = False

    def update(self, t_s: float, moving: bool) -> None:
        """The vehicle is ``moving`` (or not) from ``t_s`` on. Older times are ignored."""
        if not self._t:
            self._t.append(t_s)
            self._m.append(0.0)
            self._moving = moving
            return
        if t_s <= self._t[-1] or moving == self._moving:
            return
        self._m.append(self.reading(t_s))
        self._t.append(t_s)
        self._moving = moving

    def reading(self, t_s: float) -> float:
        """Seconds of moving from the first update until ``t_s`` (at or after the newest)."""
        if not self._t:
            return 0.0
        run = max(t_s - self._t[-1], 0.0) if self._moving else 0.0
        return self._m[-1] + run

    def since(self, now_s: float, span_s: float) -> float:
        """The earliest graph time ``t`` with ``reading(now_s) − reading(t) <= span_s``:
        what was recorded at or after it is at most ``span_s`` of moving old. When the
        vehicle has not yet moved that long, the lowest finite float: everything recorded
        holds, and a cell never recorded (``-inf``) still does not."""
        target = self.reading(now_s) - span_s
        if target <= 0.0:
            return -sys.float_info.max
        i = bisect.bisect_left(self._m, target)
        if i == 0:
            return self._t[0]
        # The clock passed ``target`` moving, after breakpoint i − 1.
        return self._t[i - 1] + (target - self._m[i - 1])


class DriftClock:
    """How far the odometry's heading may have drifted since each moment: the memory's other
    limit (:mod:`agent.control.clearance`).

    Space remembered clear was placed by the odometry of when it was seen; the vehicle is
    placed by today's. Between the two, the heading's error grows with the base's systematic
    wheel errors (:mod:`agent.sim.odometry`): the right-minus-left scale error turns the
    heading in proportion to the *signed* distance driven (``ratio_rad_per_m``, 1σ), the
    track's error in proportion to the signed turn (``track_per_rad``); and the wheels' slip
    adds a random walk (``slip_rad2_per_m`` of variance per metre rolled). The heading's σ
    between a moment and now is then

        σ² = (ratio·ΔS)² + (track·ΔΘ)² + slip·ΔL

    with ``ΔS``, ``ΔΘ`` the signed distance and turn since, ``ΔL`` the distance rolled.
    Remembered at ``r`` from the vehicle, a cell is off by about ``r·σ``: turns on the spot
    (about 7° of heading a full turn at 2 % of track error) and long drives misplace it,
    seconds of moving alone do not say by how much. :meth:`since` is the latest moment
    before which the heading may have drifted more than a given σ: what was recorded after
    it is trusted. Standing still records nothing.
    """

    def __init__(
        self, ratio_rad_per_m: float, track_per_rad: float, slip_rad2_per_m: float
    ) -> None:
        self.ratio = ratio_rad_per_m
        self.track = track_per_rad
        self.slip = slip_rad2_per_m
        # Entries (time, signed distance, signed turn, distance rolled), oldest first.
        self._h = np.zeros((_DRIFT_KEEP, 4))
        self._n = 0
        self._pruned = False  # the oldest entries were dropped: older memory is not trusted
        self._last: tuple[float, float, float] | None = None  # x, y, yaw of the last pose
        self._now = np.zeros(4)  # the newest pose's entry, recorded or not

    def update(self, t_s: float, x: float, y: float, yaw: float) -> None:
        """The odometry's pose at ``t_s`` (``yaw`` unwrapped). Older times are ignored."""
        if self._last is not None:
            if t_s <= self._now[0]:
                return
            x0, y0, yaw0 = self._last
            ds = (x - x0) * math.cos(yaw0) + (y - y0) * math.sin(yaw0)
            self._now += (0.0, ds, yaw - yaw0, abs(ds))
        self._now[0] = t_s
        self._last = (x, y, yaw)
        if self._n:
            moved = self._now[1:3] - self._h[self._n - 1, 1:3]
            if abs(float(moved[0])) + abs(float(moved[1])) <= _DRIFT_STEP:
                return
        if self._n == _DRIFT_KEEP:  # the oldest half goes (and with it its memory)
            half = _DRIFT_KEEP // 2
            self._h[:half] = self._h[half:]
            self._n = half
            self._pruned = True
        self._h[self._n] = self._now
        self._n += 1

    def _variance(self, rows: FloatArray) -> FloatArray:
        now = self._now
        return np.asarray(
            (self.ratio * (now[1] - rows[..., 1])) ** 2
            + (self.track * (now[2] - rows[..., 2])) ** 2
            + self.slip * (now[3] - rows[..., 3]),
            dtype=np.float64,
        )

    def sigma_since(self, t_s: float) -> float:
        """The heading's σ (rad) accumulated from ``t_s`` until now (the newest pose)."""
        if not self._n:
            return 0.0
        i = max(int(np.searchsorted(self._h[: self._n, 0], t_s, side="right")) - 1, 0)
        return math.sqrt(float(self._variance(self._h[i])))

    def since(self, sigma_rad: float) -> float:
        """The graph time after which the heading has drifted by no more than
        ``sigma_rad`` (1σ) to now; the lowest finite float when it never has."""
        over = np.flatnonzero(self._variance(self._h[: self._n]) > sigma_rad**2)
        if over.size:
            return float(self._h[int(over[-1]), 0])
        if self._pruned:
            return float(self._h[0, 0])
        return -sys.float_info.max


_DRIFT_STEP = 1e-3  # m or rad: a new entry once the pose has moved this much
_DRIFT_KEEP = 8192  # entries (about 160 s of driving at the odometry's 50 Hz)
