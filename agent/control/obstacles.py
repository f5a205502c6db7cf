"""The environment vector's obstacles as inflated capsules, movers swept along their path.

Every obstacle becomes a capsule (the points within ``radius + inflation`` of a segment
``a → b``, ``odom``):

* a segment or docking target: its end points, radius 0;
* a corner or occluding edge: the point, radius 0;
* a cylinder: its centre, radius its radius.

**Inflation by the covariance.** With ``P`` the 2 × 2 position block of the obstacle's
covariance and ``λ_max`` its larger eigenvalue, the inflation is

    η = min(k·√λ_max, η_cap) + margin

``k`` = 3 (``covariance_sigmas``): the obstacle's true place lies beyond 3σ along the worst
axis, toward the vehicle, with probability 0.13 %. A static segment (or docking target) is
a surface along a line: what moves it toward the vehicle is its place *across* the line,
which the vector's ``across_sigma_m`` gives (the largest σ over its extent, from the line's
(α, ρ) covariance), and that σ is used where the agent gives it. Its reference point's
covariance is the line's across it but, along it, the extent's midpoint's, which is the
extent's length / √12 while the segment's ends are unseen: a 0.8 m wall seen through the
window had λ_max of 0.22 m, its inflation capped at 0.25 m on both faces, and a park at a
goal 0.15 m from a wall could never turn (measured, random run 37 of seed 0).

The cap ``η_cap`` keeps a coasting static track's growing σ from closing every passage
(beyond it the obstacle stays where it is believed to be). A mover's cap is far wider
(``mover_inflation_cap_m``): its σ at the horizon is mostly its velocity's, and a walker
glimpsed for a few scans, its velocity known to tens of cm/s, may be anywhere in that spread
(capped at the static 0.25 m, the controller's capsule of such a walker held its estimate
and missed the walker by a metre; measured in the random worlds with the static world known,
``tests.unit.control.oracle_closed_loop``).

**Movers.** An obstacle whose speed ``s`` exceeds ``mover_speed_m_s``, and exceeds
``mover_significance`` times its velocity's σ along its direction ``u`` (``s² > k² uᵀ P_vv
u``: a track whose velocity is mostly its prior's spread is not known to move), is swept
along its velocity
``v`` over the horizon ``T``: ``b = a + v·T`` (a segment's two ends are replaced by its
midpoint, radius half its length), and inflated by its covariance at the horizon's end,

    P(T) = P_pp + T (P_pv + P_vp) + T² P_vv      (constant-velocity prediction)

so the capsule holds everywhere it may be until ``stamp + T``.

**Movers that leave the vector** are kept on their walks (:mod:`agent.control.walkways`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agent.arrays import BoolArray, FloatArray, largest_sigma
from agent.compiled import fresh_floats as _fresh
from agent.control import obstacles_kernels as kernels
from agent.control.settings import ControllerSettings
from agent.control.view import EnvironmentView
from agent.planning.environment import CYLINDER, DOCKING, SEGMENT

__all__ = [
    "Capsules",
    "capsules_from_view",
    "capsules_from_view_reference",
    "largest_sigma",
]


@dataclass(frozen=True, eq=False)
class Capsules:
    """Obstacles as capsules over ``k`` (``odom``).

    Attributes
    ----------
    a, b
        (k, 2) m: the core segment's ends (equal for a point).
    radius
        (k,) m: the obstacle's own radius about the core (a cylinder's; 0 otherwise).
    inflation
        (k,) m: added for uncertainty and margin.
    moving
        (k,) whether the obstacle is a mover (swept along its velocity).
    obstacle_id
        (k,) the vector's ids.
    """

    a: FloatArray
    b: FloatArray
    radius: FloatArray
    inflation: FloatArray
    moving: BoolArray
    obstacle_id: NDArray[np.int64]

    def __len__(self) -> int:
        return int(self.radius.size)

    @property
    def reach(self) -> FloatArray:
        """(k,) m: radius plus inflation."""
        return self.radius + self.inflation

    def select(self, mask: BoolArray) -> Capsules:
        return Capsules(
            self.a[mask], self.b[mask], self.radius[mask], self.inflation[mask],
            self.moving[mask], self.obstacle_id[mask],
        )  # fmt: skip

    def joined(self, other: Capsules) -> Capsules:
        """These capsules and ``other``'s, in one set."""
        if not len(other):
            return self
        return Capsules(
            np.concatenate([self.a, other.a]), np.concatenate([self.b, other.b]),
            np.concatenate([self.radius, other.radius]),
            np.concatenate([self.inflation, other.inflation]),
            np.concatenate([self.moving, other.moving]),
            np.concatenate([self.obstacle_id, other.obstacle_id]),
        )  # fmt: skip


def capsules_from_view(view: EnvironmentView, settings: ControllerSettings) -> Capsules:
    """The view's obstacles as inflated capsules (module docstring), in one compiled pass
    (:func:`agent.control.obstacles_kernels.capsule_arrays`)."""
    a, b, radius, inflation, moving = kernels.capsule_arrays(
        np.array(view.kind, dtype=np.uint8), _fresh(view.position_xy), _fresh(view.velocity_xy),
        _fresh(view.extent), _fresh(view.covariance), _fresh(view.across_sigma_m),
        float(settings.mover_speed_m_s), float(settings.mover_significance),
        float(settings.mover_horizon_s), float(settings.covariance_sigmas),
        float(settings.inflation_cap_m), float(settings.mover_inflation_cap_m),
        float(settings.obstacle_margin_m),
    )  # fmt: skip
    return Capsules(a, b, radius, inflation, moving, np.asarray(view.obstacle_id, dtype=np.int64))


def capsules_from_view_reference(view: EnvironmentView, settings: ControllerSettings) -> Capsules:
    """:func:`capsules_from_view` in numpy (80 µs a vector, mostly call overhead): the
    reference the tests compare its kernel with."""
    kind = view.kind
    pos = view.position_xy
    vel = view.velocity_xy
    ext = view.extent
    is_segment = (kind == SEGMENT) | (kind == DOCKING)
    a = np.where(is_segment[:, None], ext[:, 0:2], pos)
    b = np.where(is_segment[:, None], ext[:, 2:4], pos)
    radius = np.where(kind == CYLINDER, np.abs(ext[:, 0]), 0.0)
    s2 = vel[:, 0] * vel[:, 0] + vel[:, 1] * vel[:, 1]
    Pv = view.covariance[:, 2:, 2:]
    along = vel[:, 0] * (Pv[:, 0, 0] * vel[:, 0] + Pv[:, 0, 1] * vel[:, 1]) + vel[:, 1] * (
        Pv[:, 1, 0] * vel[:, 0] + Pv[:, 1, 1] * vel[:, 1]
    )
    k = settings.mover_significance
    moving = (np.sqrt(s2) > settings.mover_speed_m_s) & (s2 * s2 > k * k * along)
    T = settings.mover_horizon_s
    P = view.covariance
    P_pos = P[:, :2, :2]
    P_future = P_pos + T * (P[:, :2, 2:] + P[:, 2:, :2]) + T * T * P[:, 2:, 2:]
    sigma = largest_sigma(np.where(moving[:, None, None], P_future, P_pos))
    if view.across_sigma_m.size == kind.size:
        sigma = np.where(is_segment & ~moving, view.across_sigma_m, sigma)
    cap = np.where(moving, settings.mover_inflation_cap_m, settings.inflation_cap_m)
    inflation = np.minimum(settings.covariance_sigmas * sigma, cap) + settings.obstacle_margin_m
    # A moving segment: its midpoint, radius half its length, swept like a cylinder.
    half_length = 0.5 * np.hypot(*(ext[:, 2:4] - ext[:, 0:2]).T)
    radius = np.where(moving & is_segment, half_length, radius)
    a = np.where(moving[:, None], pos, a)
    b = np.where(moving[:, None], pos + vel * T, b)
    return Capsules(
        a=np.ascontiguousarray(a, dtype=np.float64),
        b=np.ascontiguousarray(b, dtype=np.float64),
        radius=np.asarray(radius, dtype=np.float64),
        inflation=np.asarray(inflation, dtype=np.float64),
        moving=np.asarray(moving, dtype=np.bool_),
        obstacle_id=np.asarray(view.obstacle_id, dtype=np.int64),
    )
