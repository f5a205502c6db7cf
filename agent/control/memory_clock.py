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
import sys

__all__ = ["MovingClock"]


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
