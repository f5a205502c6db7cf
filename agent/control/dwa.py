"""The baseline: the dynamic window approach (Fox, Burgard & Thrun 1997), on the same inputs.

**Search space.** The *dynamic window*: the twists reachable within one control period ``Δt``
from the last command ``(v₀, ω₀)`` under the acceleration limits,

    V_d = [v₀ − a Δt, v₀ + a Δt] × [ω₀ − α Δt, ω₀ + α Δt]

within the platform's limits and forward only (``v >= 0``, as in the paper), sampled on a
``dwa_speeds`` × ``dwa_yaw_rates`` grid. Each twist drives a circular arc.

**Admissible twists.** The paper admits a twist when the robot can stop before the nearest
obstacle on its arc, ``v <= √(2·dist·a)``. Here the rule is the controller's own (same
safety for both planners): the braking envelope, one period plus the latency and then
braking along the arc, must lie in known clear space (:mod:`agent.control.clearance`, eq. 1).

**Objective.** ``G(v, ω) = α·heading + β·dist + γ·velocity``, each term normalised over the
admissible twists (divided by its largest value):

* ``heading = 1 − |θ_goal − θ|/π`` at the pose reached after one period at ``(v, ω)`` and
  braking, ``θ_goal`` the bearing of the goal from there (the paper's 180° − angle);
* ``dist``: the free travel along the arc (the distance to the first space that is not
  known clear or is an obstacle), capped at the check's reach;
* ``velocity = v / v_max``.

The paper also smooths ``G`` over the window; with 55 samples that is left out. It has no
memory and no global view: in a dead end every admissible twist points further in, the
local minimum the method is known for.
"""

from __future__ import annotations

import math

import numpy as np

from agent.arrays import FloatArray
from agent.control.clearance import LocalState, max_scale
from agent.control.geometry import arc_end_points, roll_out, unit_motion, wrap_angle
from agent.control.local_planner import Plan
from agent.control.settings import ControllerSettings
from agent.kinematics.vehicle import VehicleSpec

__all__ = ["DynamicWindowPlanner"]


class DynamicWindowPlanner:
    """The dynamic window approach (module docstring)."""

    def __init__(self, spec: VehicleSpec, settings: ControllerSettings) -> None:
        self.spec = spec
        self.settings = settings

    def window(self, v0: float, w0: float, dt_s: float) -> tuple[FloatArray, FloatArray]:
        """The sampled dynamic window about the last command: ``(v, w)``, each (m,)."""
        spec, st = self.spec, self.settings
        v_lo = max(0.0, v0 - spec.max_accel_m_s2 * dt_s)
        v_hi = min(spec.max_speed_m_s, max(v0, 0.0) + spec.max_accel_m_s2 * dt_s)
        w_lo = max(-spec.max_yaw_rate_rad_s, w0 - spec.max_yaw_accel_rad_s2 * dt_s)
        w_hi = min(spec.max_yaw_rate_rad_s, w0 + spec.max_yaw_accel_rad_s2 * dt_s)
        v_hi = max(v_hi, v_lo)
        w_hi = max(w_hi, w_lo)
        vs = np.linspace(v_lo, v_hi, st.dwa_speeds)
        ws = np.linspace(w_lo, w_hi, st.dwa_yaw_rates)
        V, W = np.meshgrid(vs, ws, indexing="ij")
        return V.ravel(), W.ravel()

    def choose(
        self,
        pose: FloatArray,
        state: LocalState,
        goal_xy: FloatArray,
        v0: float,
        w0: float,
        dt_s: float,
        tau_s: float,
    ) -> Plan:
        """The best admissible twist of the window about ``(v0, w0)`` from ``pose`` (3,)."""
        spec, st = self.spec, self.settings
        v, w = self.window(v0, w0, dt_s)
        d_free = state.free_travel(pose, v, w)
        lam = max_scale(v, w, d_free, spec, tau_s, st.stop_margin_m)
        admissible = lam >= 1.0 - 1e-9
        if not admissible.any():
            return Plan(0.0, 0.0, np.zeros((0, 2)), "blocked")
        u = np.abs(v) + spec.circumradius_m * np.abs(w)
        t_brake = np.maximum(v / spec.max_accel_m_s2, np.abs(w) / spec.max_yaw_accel_rad_s2)
        d_pred = u * (dt_s + 0.5 * t_brake)
        mv, mw = unit_motion(v, w, spec.circumradius_m)
        px, py, th = arc_end_points(mv, mw, d_pred, pose)
        bearing = np.arctan2(goal_xy[1] - py, goal_xy[0] - px)
        heading = 1.0 - np.abs(wrap_angle(bearing - (pose[2] + th))) / math.pi
        dist = np.minimum(d_free, st.sweep_reach_m)
        velocity = v / spec.max_speed_m_s

        def normalised(term: FloatArray) -> FloatArray:
            top = float(term[admissible].max())
            return term / top if top > 0.0 else term

        G = (
            st.dwa_heading * normalised(heading)
            + st.dwa_clearance * normalised(dist)
            + st.dwa_velocity * normalised(velocity)
        )
        G = np.where(admissible, G, -np.inf)
        best = int(np.argmax(G))
        d_end = min(u[best] * st.horizon_s, float(d_free[best]))
        rollout = roll_out(pose, mv[best], mw[best], d_end, 6)
        return Plan(float(v[best]), float(w[best]), rollout, "")
