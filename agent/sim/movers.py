"""Moving obstacles: cylinders that walk a polyline back and forth at constant speed.

Frames follow REP-103 (x forward, y left); metres, seconds, world frame.

A mover is a circle of radius ``radius_m`` whose centre walks its ``path`` (waypoints) from
the first point to the last at ``speed_m_s``, turns round at once, walks back, and so on
(ping-pong). With ``L`` the path's length, the arc length walked from the first point at time
``t`` is ``s(t) = speed·t`` folded into ``[0, L]``: ``u = (speed·t) mod 2L``, ``s = u`` while
``u <= L``, else ``2L - u``. The velocity is ``±speed`` along the segment the centre is on
(``+`` on the way out). Turning round is instantaneous: a real walker would slow down, but
the tracker's constant-velocity model is then meant to be tested on the plain reversal.

Time base: ``t`` is the graph's clock in seconds, the one every stage is handed (``now_s``),
so the world simulator (which publishes the movers' truth) and the simulated head (which
places them in each beam) agree on where a mover is without exchanging a message; in
lock-step the clock starts where the runner starts it, in processes it is the Unix time, so a
mover's phase there is the clock modulo its period ``2L / speed``. Evaluated as
``(t mod (2L/speed))·speed``, a clock of 1.8e9 s still places a mover to within a
micrometre.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from agent.arrays import FloatArray
from agent.sim.movers_kernels import place_movers

__all__ = ["MOVER_GAP_M", "Mover", "mover_states", "walks_apart"]


@dataclass(frozen=True, eq=False)
class Mover:
    """One moving cylinder.

    Attributes
    ----------
    radius_m
        Radius, metres, > 0.
    reflectivity
        Relative reflectivity, > 0 (1.0 = off-white cardboard).
    path
        (p, 2) float64 waypoints, metres, world frame; p >= 2; read-only. Neighbouring
        points differ, unless every point is the same (a mover that stands still).
    speed_m_s
        Walking speed along the path, m/s, >= 0. A path of zero length needs speed 0.

    Raises
    ------
    ValueError
        For values outside the above (world files are checked with clear messages before
        they get here, by :mod:`agent.sim.world_checks`).
    """

    radius_m: float
    reflectivity: float
    path: FloatArray
    speed_m_s: float
    _cumulative: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        path = np.array(self.path, dtype=np.float64, copy=True)
        if path.ndim != 2 or path.shape[1] != 2 or path.shape[0] < 2:
            raise ValueError(f"Mover.path must be (p, 2) with p >= 2, got shape {path.shape}")
        if not np.all(np.isfinite(path)):
            raise ValueError("Mover.path must be finite")
        for name in ("radius_m", "reflectivity"):
            value = float(getattr(self, name))
            if not (np.isfinite(value) and value > 0.0):
                raise ValueError(f"Mover.{name} must be finite and > 0, got {value!r}")
            object.__setattr__(self, name, value)
        speed = float(self.speed_m_s)
        if not (np.isfinite(speed) and speed >= 0.0):
            raise ValueError(f"Mover.speed_m_s must be finite and >= 0, got {speed!r}")
        object.__setattr__(self, "speed_m_s", speed)
        steps = np.hypot(*np.diff(path, axis=0).T)
        if np.any(steps == 0.0) and not np.all(steps == 0.0):
            raise ValueError("Mover.path has two equal neighbouring points")
        if np.all(steps == 0.0) and speed != 0.0:
            raise ValueError("Mover.path has zero length: its speed must be 0")
        cumulative = np.concatenate([[0.0], np.cumsum(steps)])
        path.flags.writeable = False
        cumulative.flags.writeable = False
        object.__setattr__(self, "path", path)
        object.__setattr__(self, "_cumulative", cumulative)

    @property
    def length_m(self) -> float:
        """Length of the path, metres."""
        return float(self._cumulative[-1])

    @property
    def period_s(self) -> float:
        """Time for a walk out and back, seconds (inf for a mover that stands still)."""
        if self.speed_m_s == 0.0 or self.length_m == 0.0:
            return float("inf")
        return 2.0 * self.length_m / self.speed_m_s

    def states(self, t_s: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Centre and velocity at times ``t_s`` (any shape ``S``), graph clock, seconds.

        Returns
        -------
        xy, vxy
            ``S + (2,)`` float64: centre (m) and velocity (m/s), world frame.
        """
        t = np.asarray(t_s, dtype=np.float64)
        shape = t.shape
        t = t.reshape(-1)
        period = self.period_s
        if not np.isfinite(period):
            xy = np.broadcast_to(self.path[0], (t.size, 2)).copy()
            return xy.reshape((*shape, 2)), np.zeros((*shape, 2))
        length = self.length_m
        walked = np.mod(t, period) * self.speed_m_s  # in [0, 2L]
        outward = walked <= length
        arc = np.where(outward, walked, 2.0 * length - walked)
        cum = self._cumulative
        seg = np.clip(np.searchsorted(cum, arc, side="right") - 1, 0, cum.size - 2)
        start, step = self.path[seg], self.path[seg + 1] - self.path[seg]
        seg_len = cum[seg + 1] - cum[seg]
        frac = (arc - cum[seg]) / seg_len
        xy = start + frac[:, None] * step
        sign = np.where(outward, self.speed_m_s, -self.speed_m_s)
        vxy = (sign / seg_len)[:, None] * step
        return xy.reshape((*shape, 2)), vxy.reshape((*shape, 2))


def mover_states(movers: Sequence[Mover], t_s: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Centres and velocities of ``m`` movers at times ``t_s`` (graph clock, seconds).

    Parameters
    ----------
    movers
        The movers (a world's :attr:`~agent.sim.world.World.movers`).
    t_s
        A scalar time, or (n,) times.

    Returns
    -------
    xy, vxy
        For a scalar time (m, 2) each; for (n,) times (m, n, 2): centres in metres and
        velocities in m/s, world frame. One compiled pass over every mover and time at once
        (:func:`agent.sim.movers_kernels.place_movers`: the world simulator asks at every
        tick, the head at every sweep), with the same arithmetic as :meth:`Mover.states`, so
        the two agree to the bit.
    """
    t = np.asarray(t_s, dtype=np.float64)
    if t.ndim > 1:
        raise ValueError(f"t_s must be a scalar or (n,) times, got shape {t.shape}")
    shape = (len(movers), *t.shape, 2)
    if not movers:
        return np.empty(shape), np.empty(shape)
    pack = _packed(tuple(movers))
    xy, vxy = place_movers(
        np.ascontiguousarray(t.reshape(-1)), pack.path, pack.cumulative, pack.speed,
        pack.period, pack.length, pack.last_segment, pack.still,
    )  # fmt: skip
    # (n, m, 2) as computed; (m, n, 2) views of it (a caller wanting time-major arrays
    # swaps the axes back for free).
    return np.swapaxes(xy, 0, 1).reshape(shape), np.swapaxes(vxy, 0, 1).reshape(shape)


MOVER_GAP_M = 0.1
"""Least gap between two movers' bodies that the world generators allow, metres: people
pass one another, shoulder to shoulder at the closest (:func:`walks_apart`)."""
WALK_CHECK_HORIZON_S = 300.0
"""How long :func:`walks_apart` follows the movers, seconds: longer than any run the
benches and the evaluation drive in lock-step (whose clock starts at 0)."""
WALK_CHECK_STEP_S = 0.01
"""Its time step: two movers close at most 2 × 0.8 m/s, 1.6 cm a step."""


def walks_apart(
    movers: Sequence[Mover],
    candidate: Mover,
    gap_m: float = MOVER_GAP_M,
    horizon_s: float = WALK_CHECK_HORIZON_S,
) -> bool:
    """Whether ``candidate``'s body stays at least ``gap_m`` from every one of ``movers``'
    bodies (surface to surface) at every time from 0 to ``horizon_s`` (checked every
    :data:`WALK_CHECK_STEP_S`).

    Movers walk blindly into the vehicle, but two of them never pass through each other:
    solid bodies cannot, and where two simulated ones did, the sensor saw their union as
    one body whose two tracks were no longer either's (``bench tracking``, forward, 100
    scenes: two such crossings were 75 % of the movers' NEES). The world generators redraw
    a mover that would.
    """
    if not movers:
        return True
    t = np.arange(0.0, horizon_s, WALK_CHECK_STEP_S)
    others, _ = mover_states(movers, t)  # (m, n, 2)
    own, _ = mover_states([candidate], t)
    reach = np.array([m.radius_m for m in movers]) + candidate.radius_m + gap_m
    distance = np.hypot(*(others - own).transpose(2, 0, 1))  # (m, n)
    return bool(np.all(distance.min(axis=1) >= reach))


@dataclass(frozen=True, eq=False)
class _Packed:
    """Movers' paths as padded arrays: (m, P, 2) points, (m, P) arc lengths (+inf past each
    path's end), and per mover its speed, period, length, last segment and whether it
    stands still."""

    path: FloatArray
    cumulative: FloatArray
    speed: FloatArray
    period: FloatArray
    length: FloatArray
    last_segment: npt.NDArray[np.int64]
    still: npt.NDArray[np.bool_]


@functools.lru_cache(maxsize=32)
def _packed(movers: tuple[Mover, ...]) -> _Packed:
    points = max(m.path.shape[0] for m in movers)
    path = np.zeros((len(movers), points, 2))
    cumulative = np.full((len(movers), points), np.inf)
    for j, m in enumerate(movers):
        k = m.path.shape[0]
        path[j, :k] = m.path
        path[j, k:] = m.path[-1]
        cumulative[j, :k] = m._cumulative
    period = np.array([m.period_s for m in movers])
    return _Packed(
        path=path,
        cumulative=cumulative,
        speed=np.array([m.speed_m_s for m in movers]),
        period=np.where(np.isfinite(period), period, 1.0),
        length=np.array([m.length_m for m in movers]),
        last_segment=np.array([m.path.shape[0] - 2 for m in movers], dtype=np.int64),
        still=~np.isfinite(period),
    )
