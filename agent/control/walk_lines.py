"""A walker's line from its trail: the line through the places the vector put one mover.

The vector's velocity of a walker says which way it goes to tens of degrees. Measured in
``evaluate``'s random runs 0-3, 7 and 8 of seed 0 (``active``, the odometry's drift), over
the 1,042 vectors in which a mover of the controller (:func:`capsules_from_view`) was a
true walker: its velocity's direction was 23° off the walker's at the median (47° at the
90th percentile), no better for tracks 20 vectors old than for new ones, and its covariance
said 58° (1σ) at the median. Swept over the braking horizon and inflated by 3σ of that,
every walker's capsule was the 1.5 m cap wide, and a vehicle 1.5 m beside a walk stood
"yielding" for as long as the walker walked it.

The worlds' walkers keep to their lines, and the places the vector gave one mover lie along
its line whichever way it walked: the line fitted to the last ``trail_n`` of them
(:func:`fit_line`, the principal axis of the places) was 1.0° off at the median (5.4° at
the 90th percentile) where it could be fitted (at least ``min_points`` places spanning
``min_span_m`` along it: 66 % of those vectors).

**Its σ.** With ``s_i`` the places along the line from their mean and ``e`` the RMS of their
offsets across it (at least ``floor_m``, the places' own noise), the direction's σ is

    σ_θ = c · e / √(Σ s_i²)

the least-squares slope's, times ``c`` = 2: the places are the tracker's filtered
estimates, each correlated with the last, and the formula for independent ones (``c`` = 1)
put 4.3 % of the errors beyond 3σ; with ``c`` = 2, 0.4 % (on the vectors above).

**A mover on its line** (:func:`movers_on_lines`): its velocity is taken along the line
(the vector's velocity projected on it: ``s = v·u``) and its capsule swept ``s·T`` along
it; inflated by 3σ of its place *across* the line at the horizon's end,
``hypot(σ_across, σ_θ·s·T)``, and lengthened at each end by what 3σ of its place *along*
the line (position and speed, ``P(T)``) adds beyond that: it may be ahead of or behind its
estimate along its line, not off it.

Stated limit: a walker that leaves its line (a path with a corner) is off the fitted line by
more than the capsule holds until the trail has turned with it; the worlds' random walkers
walk straight lines.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from agent.arrays import FloatArray
from agent.control.obstacles import Capsules

__all__ = ["LineFit", "fit_line", "movers_on_lines"]

_CORRELATION = 2.0  # c above


@dataclass(frozen=True)
class LineFit:
    """A trail's line: ``direction`` (2,) unit (either sense), ``sigma_rad`` its σ."""

    direction: FloatArray
    sigma_rad: float

    def toward(self, velocity: FloatArray) -> FloatArray:
        """(2,) the line's unit direction in the sense of ``velocity`` (2,)."""
        sense = 1.0 if float(self.direction @ velocity) >= 0.0 else -1.0
        return np.asarray(sense * self.direction, dtype=np.float64)


def fit_line(
    xy: FloatArray, min_points: int = 5, min_span_m: float = 0.3, floor_m: float = 0.02
) -> LineFit | None:
    """The line through the places ``xy`` (n, 2) (module docstring), or ``None`` when
    there are fewer than ``min_points`` or they span less than ``min_span_m`` along it."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if len(xy) < min_points:
        return None
    centred = xy - xy.mean(axis=0)
    # The principal axis: the eigenvector of the places' scatter with the larger eigenvalue.
    _, vectors = np.linalg.eigh(centred.T @ centred)
    u = vectors[:, 1]
    along = centred @ u
    if float(along.max() - along.min()) < min_span_m:
        return None
    across = centred @ np.array([-u[1], u[0]])
    e = max(math.sqrt(float(np.mean(across * across))), floor_m)
    sigma = _CORRELATION * e / math.sqrt(float(np.sum(along * along)))
    return LineFit(np.asarray(u, dtype=np.float64), sigma)


def movers_on_lines(
    capsules: Capsules,
    velocity_xy: FloatArray,
    covariance: FloatArray,
    lines: dict[int, LineFit],
    horizon_s: float,
    sigmas: float,
    cap_m: float,
    margin_m: float,
) -> tuple[Capsules, FloatArray]:
    """The movers of ``capsules`` whose id has a line in ``lines`` re-swept along it
    (module docstring), and every obstacle's velocity (``velocity_xy`` (k, 2), the
    vector's, with those movers' taken along their lines). ``covariance`` (k, 4, 4) the
    vector's; the others are returned as they were."""
    velocity = np.array(velocity_xy, dtype=np.float64, copy=True)
    rows = [
        k for k in np.flatnonzero(capsules.moving).tolist()
        if int(capsules.obstacle_id[k]) in lines
    ]  # fmt: skip
    if not rows:
        return capsules, velocity
    a, b = capsules.a.copy(), capsules.b.copy()
    inflation = capsules.inflation.copy()
    T = horizon_s
    for k in rows:
        line = lines[int(capsules.obstacle_id[k])]
        u = line.toward(velocity[k])
        n = np.array([-u[1], u[0]])
        s = float(u @ velocity[k])
        P = covariance[k]
        P_future = P[:2, :2] + T * (P[:2, 2:] + P[2:, :2]) + T * T * P[2:, 2:]
        across = math.hypot(math.sqrt(max(float(n @ P[:2, :2] @ n), 0.0)), line.sigma_rad * s * T)
        along_now = math.sqrt(max(float(u @ P[:2, :2] @ u), 0.0))
        along_then = math.sqrt(max(float(u @ P_future @ u), 0.0))
        grow = min(sigmas * across, cap_m)
        p = capsules.a[k]
        a[k] = p - min(max(sigmas * along_now - grow, 0.0), cap_m) * u
        b[k] = p + (s * T + min(max(sigmas * along_then - grow, 0.0), cap_m)) * u
        inflation[k] = grow + margin_m
        velocity[k] = s * u
    refined = Capsules(a, b, capsules.radius, inflation, capsules.moving, capsules.obstacle_id)
    return refined, velocity
