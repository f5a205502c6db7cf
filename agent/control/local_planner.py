"""The controller's own local planner: arcs scored on the navigation field.

**Method.** A fixed set of ``m`` motions: forward
arcs of curvature ``κ ∈ {0, ±0.15, ±0.3, ±0.6, ±1, ±1.5, ±2.2, ±3}`` /m, each at the
fastest speed the platform allows on it (``v = min(v_max, ω_max/|κ|)``, ``w = κ v``),
rotations on the spot at ±1 rad/s, and slow reverse arcs (−0.2 m/s, ``κ ∈ {0, ±1}``). For each:

1. its free travel ``d_free`` in known clear space (:meth:`LocalState.free_travel`) and the
   largest scale ``λ`` that keeps it admissible (:func:`agent.control.clearance.max_scale`,
   eq. 1 there): the candidate is ``λ·(v, w)``, the fastest safe speed along that arc;
2. a roll-out of ``horizon_s`` at that twist, cut where the free travel ends, to an end pose
   ``(x_e, y_e, θ_e)`` (a rotation stops turning once it faces the field's descent);
3. a score, in seconds, estimating the time still needed from there:

       J = C(x_e, y_e)/v_max + h · |θ_e − θ*(x_e, y_e)|/ω_max
           + c · max(0, d_want − d_free) + R · [reverse] + W(e)

   (the last two terms: translating arcs only) with ``C`` the navigation field's
   cost-to-go (:mod:`agent.control.navigation`), ``θ*``
   the bearing from the end to the point 1 m down the field's path from the vehicle (pure
   pursuit: the path bends round what lies ahead, where the local gradient would point
   straight on), ``h`` = ``heading_weight``, ``c`` =
   ``clearance_weight``, ``d_want`` = ``clearance_want_m`` and ``R`` = 1 s against reversing
   blind; ``W(e)`` charges an end where the outline lies ``e`` deep in the walk of a
   walker that may come (either way) before the vehicle, there at the horizon's end, could
   leave it (:func:`agent.control.give_way.walk_danger`): ``walk_charge_s · (1 + e /
   1 m)`` where ``e > 0``, else 0. The lowest ``J`` wins. Where every move scores worse
   than standing still (a tight spot: the vehicle must back off before it can turn), after
   ``stuck_s`` without moving the planner drops standing still and the last two terms, and
   takes the best move (one that goes somewhere: a rotation toward a way the vehicle
   already faces goes nowhere).

**Why this.** The field has no local minimum but the goal, so following it escapes dead ends
that stop a planner scoring distance to the goal; the arcs keep what the field cannot: the
vehicle's rectangular outline, its heading, its dynamics and the safety rule, checked
exactly on each arc rather than on the field's inflated grid. Scoring each arc at its
fastest admissible speed makes speed part of the choice where it matters: an arc that must
stop short of unknown space ends further up the field. Rotating on the spot is a candidate
like any other, which is how the vehicle turns round in a dead end.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from agent.arrays import FloatArray
from agent.control import geometry_kernels as kernels
from agent.control.clearance import LocalState, max_scale, max_scale_reference
from agent.control.geometry import (
    arc_end_points,
    outline_perimeter,
    roll_out,
    sweep_points,
    unit_motion,
    wrap_angle,
)
from agent.control.give_way import Walkers, walk_danger
from agent.control.navigation import NavigationField
from agent.control.settings import ControllerSettings
from agent.kinematics.vehicle import VehicleSpec

__all__ = ["ArcPlanner", "Plan", "choose_reference"]

_CURVATURES = (0.0, 0.15, -0.15, 0.3, -0.3, 0.6, -0.6, 1.0, -1.0, 1.5, -1.5, 2.2, -2.2, 3.0, -3.0)
_ROTATION_RAD_S = 1.0
_REVERSE = ((-0.2, 0.0), (-0.2, 0.2), (-0.2, -0.2))
_REVERSE_PENALTY_S = 1.0
_LOOKAHEAD_M = 1.0
_ROLLOUT = 6  # points of the plan's roll-out


@dataclass(frozen=True)
class Plan:
    """A planner's choice.

    Attributes
    ----------
    speed_m_s, yaw_rate_rad_s
        The twist it wants (before the controller's ramp and safety clamp).
    rollout_xy
        (q, 2) ``odom``: where that twist leads over the horizon, nearest first.
    reason
        ``""``, ``"unknown_ahead"`` (slowed by the end of known clear space) or
        ``"blocked"`` (no motion is admissible).
    """

    speed_m_s: float
    yaw_rate_rad_s: float
    rollout_xy: FloatArray
    reason: str


class ArcPlanner:
    """Arcs scored on the navigation field (module docstring)."""

    def __init__(self, spec: VehicleSpec, settings: ControllerSettings) -> None:
        self.spec = spec
        self.settings = settings
        k = np.array(_CURVATURES)
        v = np.minimum(spec.max_speed_m_s, spec.max_yaw_rate_rad_s / np.maximum(np.abs(k), 1e-9))
        w = k * v
        rot = min(_ROTATION_RAD_S, spec.max_yaw_rate_rad_s)
        rev = np.array(_REVERSE)
        self.v = np.concatenate([v, [0.0, 0.0], rev[:, 0]])
        self.w = np.concatenate([w, [rot, -rot], rev[:, 1]])
        self.reverse = self.v < 0.0
        self.rotation = self.v == 0.0
        self.v_unit, self.w_unit = unit_motion(self.v, self.w, spec.circumradius_m)
        self.outline = outline_perimeter(spec, settings.outline_spacing_m)

    def walk_charge(self, end: FloatArray, end_yaw: FloatArray, walkers: Walkers) -> FloatArray:
        """``W(e)`` (m,) s of arcs ending at ``end`` (m, 2), ``end_yaw`` (m,) (module
        docstring)."""
        if not len(walkers):
            return np.zeros(end.shape[0])
        st = self.settings
        points = sweep_points(np.column_stack([end, end_yaw]), self.outline)  # (m, p, 2)
        depth = walk_danger(points, walkers, self.spec, st, st.horizon_s)
        return np.asarray(
            np.where(depth > 0.0, st.walk_charge_s * (1.0 + depth), 0.0), dtype=np.float64
        )

    def capped(self, speed_cap_m_s: float | None) -> tuple[FloatArray, FloatArray]:
        """The candidate twists, each scaled down to ``speed_cap_m_s`` if given."""
        v, w = self.v, self.w
        if speed_cap_m_s is not None:
            cap = np.minimum(1.0, speed_cap_m_s / np.maximum(np.abs(v), 1e-9))
            v, w = v * cap, w * cap
        return v, w

    def choose(
        self,
        pose: FloatArray,
        state: LocalState,
        field: NavigationField,
        tau_s: float,
        speed_cap_m_s: float | None = None,
        unstick: bool = False,
        walkers: Walkers | None = None,
    ) -> Plan:
        """The best arc from ``pose`` (3,) (``odom``) now.

        ``tau_s`` is the time a command is held before braking can start (period plus
        latency); ``speed_cap_m_s`` an extra bound on speed (to stop at a goal).
        ``unstick``: the vehicle has not moved for a while although it should; standing
        still is then no candidate, nor are reversing and tight clearance charged (it may
        have to back off a little before it can turn). ``walkers`` (as of now) charge the
        arcs that end in their walks.
        """
        st, spec = self.settings, self.spec
        d_free = state.free_travel_unit(pose, self.v_unit, self.w_unit)
        v, w = self.capped(speed_cap_m_s)
        lam = max_scale(v, w, d_free, spec, tau_s, st.stop_margin_m)
        target, turn_needed = _target(field, pose)
        x, y, yaw = float(pose[0]), float(pose[1]), float(pose[2])
        # Rotations stop turning once they face it.
        v_c, w_c, u, d_end, end, end_yaw = kernels.arc_ends(
            v, w, lam, d_free, self.v_unit, self.w_unit, self.rotation, spec.circumradius_m,
            st.horizon_s, turn_needed, x, y, yaw,
        )  # fmt: skip
        cost = field.value(end)
        to_target = target - end
        # numpy's arctan2, as the reference: it differs from libm's atan2 in the last bit.
        bearing = np.arctan2(to_target[:, 1], to_target[:, 0])
        best, moving = kernels.arc_scores(
            end, end_yaw, cost, bearing, field.descent(end), u, d_free, d_end, self.rotation,
            self.reverse, float(target[0]), float(target[1]), 0.5 * field.cell_m,
            spec.max_speed_m_s, spec.max_yaw_rate_rad_s, st.heading_weight,
            st.clearance_weight, st.clearance_want_m, _REVERSE_PENALTY_S, bool(unstick),
            self.walk_charge(end, end_yaw, walkers or Walkers.none()),
        )  # fmt: skip
        reason = ""
        if not moving:
            reason = "blocked"
        elif lam[best] < 1.0 - 1e-9:
            reason = "unknown_ahead"
        v_best, w_best = float(v_c[best]), float(w_c[best])
        if self.rotation[best] and np.sign(self.w[best]) == np.sign(turn_needed):
            # Slow the turn to stop facing the descent.
            w_stop = math.sqrt(spec.max_yaw_accel_rad_s2 * abs(turn_needed))
            w_best = math.copysign(min(abs(w_best), w_stop, abs(turn_needed) / tau_s), w_best)
        rollout = kernels.arc_rollout(
            float(self.v_unit[best]), float(self.w_unit[best]), float(d_end[best]), _ROLLOUT,
            x, y, yaw,
        )  # fmt: skip
        return Plan(v_best, w_best, rollout, reason)


def _target(field: NavigationField, pose: FloatArray) -> tuple[FloatArray, float]:
    """The way to go: the point ``_LOOKAHEAD_M`` down the field (pure pursuit of the
    field's path, which bends round what lies ahead where a gradient would not), and the
    turn from ``pose``'s heading toward it."""
    target = field.lookahead(pose[:2], _LOOKAHEAD_M)
    turn = float(wrap_angle(math.atan2(target[1] - pose[1], target[0] - pose[0]) - pose[2]))
    return target, turn


def choose_reference(
    planner: ArcPlanner,
    pose: FloatArray,
    state: LocalState,
    field: NavigationField,
    tau_s: float,
    speed_cap_m_s: float | None = None,
    unstick: bool = False,
    walkers: Walkers | None = None,
) -> Plan:
    """:meth:`ArcPlanner.choose` in numpy, over whole arrays (what the compiled
    :mod:`agent.control.geometry_kernels` compute, 0.26 ms a command in numpy)."""
    st, spec = planner.settings, planner.spec
    d_free = state.free_travel(pose, planner.v, planner.w)
    v, w = planner.capped(speed_cap_m_s)
    lam = max_scale_reference(v, w, d_free, spec, tau_s, st.stop_margin_m)
    v_c, w_c = lam * v, lam * w
    u = np.abs(v_c) + spec.circumradius_m * np.abs(w_c)
    d_end = np.minimum(u * st.horizon_s, d_free)
    target, turn_needed = _target(field, pose)
    # Rotations stop turning once they face it.
    rot_d = np.abs(turn_needed) * spec.circumradius_m
    same_way = np.sign(planner.w) == np.sign(turn_needed)
    d_end = np.where(planner.rotation & same_way, np.minimum(d_end, rot_d), d_end)
    mv, mw = planner.v_unit, planner.w_unit
    end_x, end_y, th = arc_end_points(mv, mw, d_end, pose)
    end = np.stack([end_x, end_y], axis=1)
    end_yaw = pose[2] + th
    cost = field.value(end)
    to_target = target - end
    far = np.hypot(to_target[:, 0], to_target[:, 1]) > 0.5 * field.cell_m
    theta_star = np.where(far, np.arctan2(to_target[:, 1], to_target[:, 0]), field.descent(end))
    heading_error = np.abs(wrap_angle(end_yaw - theta_star))
    moving = u > 1e-6
    J = cost / spec.max_speed_m_s + st.heading_weight * heading_error / spec.max_yaw_rate_rad_s
    J = J + planner.walk_charge(end, end_yaw, walkers or Walkers.none())
    if unstick:  # a motion that goes nowhere (faces the way already) is no move either
        J = np.where(moving & (d_end >= kernels.NOWHERE_M), J, np.inf)
    else:
        J = J + (
            st.clearance_weight
            * np.maximum(0.0, st.clearance_want_m - d_free)
            * (moving & ~planner.rotation)
            + _REVERSE_PENALTY_S * planner.reverse
        )
    best = int(np.argmin(J))
    reason = ""
    if not moving.any():
        reason = "blocked"
    elif lam[best] < 1.0 - 1e-9:
        reason = "unknown_ahead"
    v_best, w_best = float(v_c[best]), float(w_c[best])
    if planner.rotation[best] and same_way[best]:
        # Slow the turn to stop facing the descent.
        w_stop = math.sqrt(spec.max_yaw_accel_rad_s2 * abs(turn_needed))
        w_best = math.copysign(min(abs(w_best), w_stop, abs(turn_needed) / tau_s), w_best)
    rollout = roll_out(pose, mv[best], mw[best], d_end[best], _ROLLOUT)
    return Plan(v_best, w_best, rollout, reason)
