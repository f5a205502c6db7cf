"""The movers' compiled placement (:func:`agent.sim.movers.mover_states`; why compiled:
:mod:`agent.compiled`).

The world simulator asks where the movers are at every collision test of a tick (a handful of
times), the simulated head at every beam it casts (a few hundred): in numpy each call cost
about 40 µs of small-array overhead whatever its size, several per tick. Here one pass over
every time and mover, with the arithmetic of :meth:`agent.sim.movers.Mover.states` step for
step, so that the two agree to the bit.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from agent.arrays import BoolArray, FloatArray
from agent.compiled import compiled

IntArray = npt.NDArray[np.int64]


@compiled
def place_movers(
    t: FloatArray,
    path: FloatArray,
    cumulative: FloatArray,
    speed: FloatArray,
    period: FloatArray,
    length: FloatArray,
    last_segment: IntArray,
    still: BoolArray,
) -> tuple[FloatArray, FloatArray]:
    """Centres and velocities of ``m`` movers at times ``t`` (n,), graph clock, seconds.

    Parameters
    ----------
    t
        (n,) times, seconds.
    path
        (m, P, 2) each mover's waypoints, metres, world frame, padded with its last point.
    cumulative
        (m, P) arc length at each waypoint, metres, ``+inf`` past the path's end.
    speed, period, length
        (m,) walking speed (m/s), out-and-back period (s; 1 for a mover standing still) and
        path length (m).
    last_segment
        (m,) index of each path's last segment.
    still
        (m,) whether the mover stands still (placed at its first point, velocity 0).

    Returns
    -------
    xy, vxy
        (n, m, 2) each: centres (m) and velocities (m/s), time-major. The arc walked is
        ``u = (t mod period)·speed`` folded into ``[0, L]``; the segment is the last whose
        start is at or before it (``searchsorted(..., "right") - 1``, clipped to the path).
    """
    n, m = t.size, speed.size
    xy = np.zeros((n, m, 2))
    vxy = np.zeros((n, m, 2))
    for j in range(m):
        for i in range(n):
            if still[j]:
                xy[i, j, 0] = path[j, 0, 0]
                xy[i, j, 1] = path[j, 0, 1]
                continue
            walked = (t[i] % period[j]) * speed[j]  # Python's and numpy's mod: fmod, signed as b
            outward = walked <= length[j]
            arc = walked if outward else 2.0 * length[j] - walked
            count = 0
            for p in range(cumulative.shape[1]):
                if cumulative[j, p] <= arc:
                    count += 1
            seg = min(max(count - 1, 0), last_segment[j])
            cum0 = cumulative[j, seg]
            seg_len = cumulative[j, seg + 1] - cum0
            frac = (arc - cum0) / seg_len
            sign = speed[j] if outward else -speed[j]
            for c in range(2):
                start = path[j, seg, c]
                step = path[j, seg + 1, c] - start
                xy[i, j, c] = start + frac * step
                vxy[i, j, c] = (sign / seg_len) * step
    return xy, vxy
