"""Giving way to walkers: out of a walker's walk before it may arrive, or standing still.

A mover's swept capsule that reaches the vehicle's outline stops the vehicle
(``"yielding"``). Stopping is right beside a walker's walk and wrong across it: the worlds'
walkers walk their lines blindly, as people who have not seen the vehicle would, and one
whose line crosses the standing vehicle walks into it. Measured in ``evaluate``'s random
runs 0-47 of seed 0 (``active``, perfect odometry, the seen profiles recorded): 22
collisions with walkers, 12 of them a walker meeting a vehicle stopped to yield, almost all
at a front corner, the walker crossing the vehicle's axis; every one of those walkers had
been tracked for seconds. With the walkers' true places and velocities in the vector instead
of their tracks, the same runs ended in 37 collisions, every one a walker meeting a vehicle
that stood: most in the walk of a walker that had been walking away and turned back at its
walk's end.

So a walk is a **danger** (:func:`walk_danger`) wherever its walker may come, walking either
way, before the vehicle could leave it; the controller leaves such a walk as soon as it
stands in one, not only once the capsule reaches it, and its local planner charges the arcs
that would end in one (:mod:`agent.control.local_planner`), so that it waits beside walks
rather than in them.

**The walk.** A walker ``j`` (centre ``p``, velocity ``v``, speed ``s = |v|``, radius ``r``)
walks the line through ``p`` along ``u = v/s``, its centre between ``lo`` and ``hi`` along it
from ``p`` (its *span*: where its walk was seen to turn back,
:class:`agent.control.walk_lines.WalkRegistry`; unbounded where not). The outline is *in its
walk* when any of its points within the span (``lo − h ≤ t_i ≤ hi + h``, with
``t_i = (x_i − p)·u``) lies within ``h = r + give_way_margin_m`` of that line, or such points
lie on both sides. With ``c_i`` the signed distances of those points from the line, the
displacement still needed to leave it is

    e_j = min(max(0, h − min c_i), max(0, h + max c_i))       (0: out of the walk)

A walk ends where its walker turns: taken as the whole line, a walker pacing 1.4 m up to a
pillar and back barred the line's extension 0.75 m beyond its end, across the vehicle's way
to a docking plate, and the vehicle stood before it for 80 s (the demo world, a walker
turning short of the route).

**When it comes.** The walker meets the outline after ``(min {t_i : |c_i| < h} − r) / s``
seconds (its centre's way to the first point in its walk, less its radius; points more
than ``r`` beyond its span it never meets), never if all those points lie behind it. A
walker that left the vector (:mod:`agent.control.walkways`: a run of places on its line
where it may be, as a walker at the run's middle aged so that it spans the run walking
either way) may have walked on or turned back: it comes after
``(min |t_i| − r − s·age) / s``; and so, with ``age`` 0, may any walker when it is taken to
walk *either way*, as the danger and the way out take it, except that one in the vector
whose walk was seen to reach ``onward`` further the way it walks (its places across its
tracks, :mod:`agent.control.walkways`) walks there before it can turn: it comes from
behind after ``(2·onward + |t_i| − r) / s``. The worlds' walkers turn only at their walks'
ends, so a walker that has just passed the vehicle's way and walks on to an end it was
seen at leaves the time to cross behind it (stated limit: a person who turns back short of
where they walked before).

**The danger.** With ``e_j`` the depth in walk ``j`` and ``a_j`` its walker's arrival
either way, the outline is in danger ``lead`` seconds from now when, for some ``j``,

    e_j > 0  and  a_j < lead + T(e_j) + give_way_reserve_s

with ``T(e)`` the time to move ``e`` from rest to rest at the vehicle's speed and
acceleration limits (:func:`agent.kinematics.limits.rest_to_rest_s`). The controller gives
way with ``lead = give_way_lead_s`` (1 s); the planner charges an arc whose end is in danger
with ``lead = horizon_s`` (1.5 s, when it gets there), the stricter of the two, so that the
planner does not lead the vehicle into a walk it must at once leave.

**The way out.** Among motions of the vehicle (arcs forward and back at seven curvatures,
and the turns on the spot), each rolled out in steps of 5 cm of its furthest-moving point
to 1 m, the one that leaves soonest the walk of every walker that may come (either way)
within ``give_way_horizon_s``, where

* its way out lies within the space the braking rule admits (``LocalState.free_travel``),
* it is done, from rest at the vehicle's acceleration limits, ``give_way_reserve_s`` before
  the first walker comes,
* and on the way no outline point comes within the walker's radius of where that walker
  then is (a walker in the vector walked on along ``v``),

is driven; when none is, the vehicle stands (``"yielding"``): it is not the vehicle's to
run into a walker it cannot outpace.

**Measured** (``evaluate``'s random runs 0-47 of seed 0, ``active``, paired). With the
walkers' truth in the vector (perfect odometry, the seen profiles recorded): collisions
with walkers 37 → 5 (each a walker meeting a standing vehicle), tasks done 3 → 2, mean
speed 0.113 → 0.090 m/s; taken the way they come (their velocity only), the danger and the
charge left 32. With the walkers' tracks (and the mover rules of
:mod:`agent.control.obstacles` and :mod:`agent.control.walkways`): perfect odometry and the
seen profiles, "yielding" 71 % → 64 % of the commands, mean speed 0.031 → 0.039 m/s, tasks
done 1 → 1, collisions 0 → 2 (both by the vehicle, with walkers that came from beside it
and were never in the window); the defaults (drift, aged profiles): 66 % → 59 %,
0.025 → 0.031 m/s, no collision and no task done either way.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from agent.arrays import BoolArray, FloatArray
from agent.control.clearance import LocalState
from agent.control.geometry import from_pose, motion_poses, sweep_points, unit_motion
from agent.control.settings import ControllerSettings
from agent.kinematics.limits import rest_to_rest_s
from agent.kinematics.vehicle import VehicleSpec

__all__ = ["Walkers", "WayOut", "arrival_s", "walk_danger", "walk_depth", "way_out"]

# The displacements of a motion's furthest-moving point it is rolled out at (m).
_STEPS: FloatArray = np.asarray(np.arange(1, 21) * 0.05, dtype=np.float64)
_CURVATURES = 7


@dataclass(frozen=True)
class Walkers:
    """Movers as walkers on their lines, ``odom``, at ``stamp_s``.

    Attributes
    ----------
    position, velocity
        (k, 2) m, m/s: each walker's centre and velocity at ``stamp_s`` (a remembered one's
        last, as it was ``age`` ago).
    radius
        (k,) m.
    age
        (k,) s: 0 for a walker in the vector; for a remembered one, the time since it was
        last in one (it may have walked on or turned back along its line since).
    stamp_s
        When the positions held.
    onward
        (k,) m, or empty (all 0): how far a walker in the vector walks on along its
        velocity before it may turn back: its walk was seen to reach that far that way
        (module docstring, *when it comes*); 0 where it may turn at once.
    span
        (k, 2) m, or empty (unbounded): how far back and on along its velocity from
        ``position`` its centre may go, ``(lo, hi)``, ``lo <= 0 <= hi``: where its walk was
        seen to turn back, its end; ``∓inf`` where not known (module docstring, *the walk*).
    """

    position: FloatArray
    velocity: FloatArray
    radius: FloatArray
    age: FloatArray
    stamp_s: float
    onward: FloatArray = field(default_factory=lambda: np.zeros(0))
    span: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))

    def __len__(self) -> int:
        return int(self.radius.size)

    @property
    def onward_m(self) -> FloatArray:
        """(k,) m: :attr:`onward`, zeros when not given."""
        if self.onward.size != self.radius.size:
            return np.zeros(self.radius.size)
        return self.onward

    @property
    def span_m(self) -> FloatArray:
        """(k, 2) m: :attr:`span`, unbounded when not given."""
        if self.span.shape != (self.radius.size, 2):
            return np.tile([-np.inf, np.inf], (self.radius.size, 1))
        return self.span

    @staticmethod
    def none(stamp_s: float = 0.0) -> Walkers:
        return Walkers(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0), stamp_s)

    def at(self, now_s: float) -> Walkers:
        """The walkers ``now_s``: those in the vector walked on along their velocity, the
        remembered ones aged."""
        dt = max(now_s - self.stamp_s, 0.0)
        walked = np.where((self.age == 0.0)[:, None], self.position + self.velocity * dt,
                          self.position)  # fmt: skip
        aged = np.where(self.age == 0.0, 0.0, self.age + dt)
        speed = np.hypot(self.velocity[:, 0], self.velocity[:, 1])
        walked_m = np.where(self.age == 0.0, speed * dt, 0.0)
        onward = np.maximum(self.onward_m - walked_m, 0.0)
        span = self.span_m - walked_m[:, None]
        return Walkers(walked, self.velocity, self.radius, aged, now_s, onward, span)

    def select(self, mask: BoolArray) -> Walkers:
        """The walkers where ``mask`` (k,) holds."""
        return Walkers(
            self.position[mask], self.velocity[mask], self.radius[mask], self.age[mask],
            self.stamp_s, self.onward_m[mask], self.span_m[mask],
        )  # fmt: skip


@dataclass(frozen=True)
class WayOut:
    """A motion out of the walkers' walks: its twist at the vehicle's limits (m/s, rad/s),
    its direction (the unit motion), how far its furthest-moving point goes, and when it is
    done (from rest, s)."""

    speed_m_s: float
    yaw_rate_rad_s: float
    v_unit: float
    w_unit: float
    distance_m: float
    time_s: float


def _frames(walkers: Walkers) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Each walker's line: unit direction ``u`` (k, 2), its normal ``n`` (k, 2), speed (k,)."""
    speed = np.hypot(walkers.velocity[:, 0], walkers.velocity[:, 1])
    u = walkers.velocity / np.maximum(speed, 1e-9)[:, None]
    n = np.stack([-u[:, 1], u[:, 0]], axis=1)
    return u, n, speed


def walk_depth(points: FloatArray, walkers: Walkers, margin_m: float) -> FloatArray:
    """``e_j`` (…, k) m: how far outlines ``points`` (…, p, 2) must still move to leave each
    walker's walk (module docstring); 0 where they are out of it."""
    u, n, _ = _frames(walkers)
    rel = points[..., None, :] - walkers.position  # (…, p, k, 2)
    c = np.einsum("...pkd,kd->...pk", rel, n)
    h = walkers.radius + margin_m
    # Points beyond the ends of its walk (its centre's span, its radius and the margin
    # further) are out of it.
    on = _on_walk(np.einsum("...pkd,kd->...pk", rel, u), walkers, h)
    low = np.where(on, c, np.inf).min(axis=-2)
    high = np.where(on, c, -np.inf).max(axis=-2)
    depth = np.minimum(np.maximum(h - low, 0.0), np.maximum(h + high, 0.0))
    return np.asarray(depth, dtype=np.float64)


def _on_walk(t: FloatArray, walkers: Walkers, reach: FloatArray) -> BoolArray:
    """(…, p, k): whether points at ``t`` (…, p, k) along each walker's line from its
    centre lie within ``reach`` (k,) of the part its centre may walk (:attr:`Walkers.span`)."""
    span = walkers.span_m
    return np.asarray((t >= span[:, 0] - reach) & (t <= span[:, 1] + reach), dtype=np.bool_)


def arrival_s(
    points: FloatArray, walkers: Walkers, margin_m: float, either_way: bool = False
) -> FloatArray:
    """(…, k) s: when each walker meets the outlines ``points`` (…, p, 2) walking its line
    (module docstring); ``inf`` for one walking away, or whose walk misses the outline.
    ``either_way``: every walker may turn back at any moment, as a remembered one may."""
    u, n, speed = _frames(walkers)
    rel = points[..., None, :] - walkers.position  # (…, p, k, 2)
    t = np.einsum("...pkd,kd->...pk", rel, u)
    c = np.einsum("...pkd,kd->...pk", rel, n)
    inside = (np.abs(c) < walkers.radius + margin_m) & _on_walk(t, walkers, walkers.radius)
    remembered = (walkers.age > 0.0) | either_way
    # A remembered walker may come either way; one in the vector comes along ``u``; taken
    # to come either way, one that walks on ``onward`` first comes back from there.
    way = np.where(t >= 0.0, t, np.abs(t) + 2.0 * walkers.onward_m)
    ahead = np.where(inside & (remembered | (t >= 0.0)), way, np.inf).min(axis=-2)
    # One whose centre is already past some of the outline's points in its walk, but not
    # past them all, is over the outline now.
    straddles = (inside & (t < 0.0)).any(axis=-2) & ~remembered & np.isfinite(ahead)
    gap = np.where(straddles, 0.0, ahead - walkers.radius - speed * walkers.age)
    return np.where(np.isfinite(gap), np.maximum(gap, 0.0) / np.maximum(speed, 1e-9), np.inf)


def walk_danger(
    points: FloatArray, walkers: Walkers, spec: VehicleSpec, settings: ControllerSettings,
    lead_s: float,
) -> FloatArray:  # fmt: skip
    """(…,) m: how deep outlines ``points`` (…, p, 2) lie in the walk of a walker that may
    come (either way: it may turn back) before the vehicle, there ``lead_s`` from now,
    could leave it from rest and ``give_way_reserve_s`` more (module docstring); 0 where no
    such walk holds them."""
    shape = points.shape[:-2]
    if not len(walkers):
        return np.zeros(shape)
    margin = settings.give_way_margin_m
    depth = walk_depth(points, walkers, margin)
    need = rest_to_rest_s(depth, spec.max_speed_m_s, spec.max_accel_m_s2)
    comes = arrival_s(points, walkers, margin, either_way=True)
    danger = (depth > 0.0) & (comes < lead_s + need + settings.give_way_reserve_s)
    return np.asarray(np.where(danger, depth, 0.0).max(axis=-1), dtype=np.float64)


def _limits(
    v_unit: FloatArray, w_unit: FloatArray, spec: VehicleSpec
) -> tuple[FloatArray, FloatArray]:
    """The largest rate and acceleration (m,) of unit motions (m,) within the vehicle's
    speed, yaw rate and acceleration limits."""
    av, aw = np.abs(v_unit), np.abs(w_unit)
    with np.errstate(divide="ignore"):
        rate = np.minimum(np.where(av > 0, spec.max_speed_m_s / av, np.inf),
                          np.where(aw > 0, spec.max_yaw_rate_rad_s / aw, np.inf))  # fmt: skip
        accel = np.minimum(np.where(av > 0, spec.max_accel_m_s2 / av, np.inf),
                           np.where(aw > 0, spec.max_yaw_accel_rad_s2 / aw, np.inf))  # fmt: skip
    return rate, accel


def _candidates(spec: VehicleSpec) -> tuple[FloatArray, FloatArray]:
    """Unit motions (m,): arcs forward and back at seven curvatures, and the two turns on
    the spot."""
    w = np.linspace(-1.0, 1.0, _CURVATURES) * spec.max_yaw_rate_rad_s
    v = np.concatenate([np.full(w.size, spec.max_speed_m_s), np.full(w.size, -spec.max_speed_m_s),
                        [0.0, 0.0]])  # fmt: skip
    w = np.concatenate([w, w, [spec.max_yaw_rate_rad_s, -spec.max_yaw_rate_rad_s]])
    return unit_motion(v, w, spec.circumradius_m)


def way_out(
    pose: FloatArray,
    outline: FloatArray,
    walkers: Walkers,
    local: LocalState,
    spec: VehicleSpec,
    settings: ControllerSettings,
) -> WayOut | None:
    """The soonest admissible motion out of the walks of the walkers that come (module
    docstring), or ``None``: out of every walk already, or no way out in time.

    ``walkers`` are as of now (:meth:`Walkers.at`); ``outline`` is the perimeter's points
    in ``base_link`` (p, 2)."""
    if not len(walkers):
        return None
    margin = settings.give_way_margin_m
    here = np.stack(from_pose(pose, outline[:, 0], outline[:, 1]), axis=1)
    comes = arrival_s(here, walkers, margin, either_way=True)
    coming = (comes <= settings.give_way_horizon_s) & (walk_depth(here, walkers, margin) > 0.0)
    if not coming.any():
        return None
    walkers = walkers.select(coming)
    deadline = float(comes[coming].min()) - settings.give_way_reserve_s
    if deadline <= 0.0:
        return None
    v_unit, w_unit = _candidates(spec)
    poses = motion_poses(v_unit, w_unit, _STEPS)  # (m, n, 3) in base_link
    odom = np.stack([*from_pose(pose, poses[..., 0], poses[..., 1]), pose[2] + poses[..., 2]], -1)
    points = sweep_points(odom, outline)  # (m, n, p, 2)
    out = (walk_depth(points, walkers, margin) == 0.0).all(axis=-1)  # (m, n)
    rate, accel = _limits(v_unit, w_unit, spec)
    times = rest_to_rest_s(_STEPS[None, :], rate[:, None], accel[:, None])  # (m, n)
    # On the way: no outline point within a walker's radius of where it then is.
    walked = (
        walkers.position + (walkers.age == 0.0)[:, None] * walkers.velocity * times[..., None, None]
    )  # (m, n, k, 2)
    gap = np.hypot(*np.moveaxis(points[..., :, None, :] - walked[..., None, :, :], -1, 0))
    touches = (gap < walkers.radius).any(axis=(-1, -2))  # (m, n)
    touched_before = np.cumsum(touches, axis=1) > 0
    free = local.free_travel_unit(pose, v_unit, w_unit)  # (m,)
    ok = out & ~touched_before & (_STEPS[None, :] <= free[:, None]) & (times <= deadline)
    if not ok.any():
        return None
    # Each motion's first step out of every walk that keeps the rules; the soonest wins.
    first = np.argmax(ok, axis=1)
    cost = np.where(ok.any(axis=1), times[np.arange(v_unit.size), first], np.inf)
    best = int(np.argmin(cost))
    k = int(first[best])
    return WayOut(
        float(v_unit[best] * rate[best]), float(w_unit[best] * rate[best]), float(v_unit[best]),
        float(w_unit[best]), float(_STEPS[k]), float(cost[best]),
    )  # fmt: skip
