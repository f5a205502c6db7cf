"""The vehicle controller: drives on the environment vector alone, or stops.

Three calls feed it and one asks it (the ``vehicle`` stage makes them, in one process on a
simulated clock or as its own process): :meth:`Controller.update_odometry` (the base's pose
in ``odom`` and its velocity), :meth:`Controller.update_environment` (an environment vector)
and :meth:`Controller.command` (the twist to send now). It reads nothing else: no clock, no
truth. The task's goal is in the world frame, which is ``odom`` as it was at the start.

**Safety first** (``docs/interface.md`` §5). ``command`` returns exactly zero speed and yaw
rate, mode ``"waiting"``, whenever the newest vector is missing (``"no_environment"``),
untrusted (``"sensor_not_ok"``) or outside ``[stamp, stamp + valid_for_s]``
(``"stale_environment"``), or no odometry came yet (``"no_odometry"``); it moves again on
the first fresh, trusted vector. Every other command passes the braking-envelope rule of
:mod:`agent.control.clearance` last: whatever the planner wants is scaled down until the
vehicle could stop in known clear space; a mover whose swept capsule reaches the vehicle
stops it (``"yielding"``), unless it stands in the walk of a walker that comes and can
leave it in time (``"giving_way"``, :mod:`agent.control.give_way`).

**Each call.** The pose now is the newest odometry advanced along its own twist to ``now``;
the last command's twist ``(v₀, ω₀)`` is ramped toward the wanted one within the
acceleration limits over one period, then the safety rule applies. Each vector's profile
and obstacles go into the free-space memory (:class:`~agent.control.clearance.ClearanceMap`)
and the navigation field's map (:class:`~agent.control.navigation.NavigationField`) with the
odometry's pose at the vector's stamp (interpolated), with the vehicle's own footprint (and,
at the first odometry, the start pose's clearance), and the local state of known clear
space is composed once per vector.

**Looking.** With the head's window fixed ahead, the vehicle's heading is where it looks,
and nothing beside it is ever seen from where it stands. So it looks round on the spot
before it first moves; it turns on the spot to face the way ahead (the field's path 1.2 m
on) when that is more than 0.45 rad off its heading, before the planner drives; when
navigating has made no progress (0.1 m or 0.3 rad) for 1.5 s, the planner must pick a move
(it may have to back off before it can turn) until the vehicle has moved 0.15 m or turned
0.5 rad, once; after 4.5 s without progress it backs off 0.35 m where it may (the space
just ahead of its bumper is nearer the centre of scanning than the near limit: only
distance shows it) and looks round again. Each move goes only as far as the safety rule
admits. A look begins with the vehicle standing (``look_stand_s``) with its way as the
intent; when the agent's head pans (its vectors' scanned windows lie off the heading), that
is the look, and the vehicle only turns to face the way ahead: turning all round on the
spot took 7 s a turn and cost the odometry about 7° of heading (``look_stand_s``). With such
a head, a forward motion also stops before unknown space comes nearer the bumper than the
head can see (``look_ahead_m``, :mod:`agent.control.clearance`).

**Tasks.**

* ``goto``: drive on the planner (``"driving"``; ``"escaping"`` while the field leads away
  from the goal's direction); within ``final_approach_m`` with nothing in between, steer
  straight at it; within ``goal_reach_m`` stop, and report arrived once stopped.
* ``park``: as goto, then turn on the spot to ``goal_yaw_rad`` (the long way round once the
  short way is blocked; blocked both ways, back off, look and come again), stop, arrived
  (``"parking"``). Within ``turn_watch_m`` of the goal the head is asked to look at the
  ring the turn will sweep (``watch_xy``).
* ``dock`` (``"docking"``): drive toward the goal until a docking target is seen near it
  (to within ``dock_search_m`` of the goal, then face it, then from nearer, then from
  another side of it: :func:`~agent.control.docking.search_viewpoint`); then to the start
  of the docking line, turn onto it, follow it to the stop (:mod:`agent.control.docking`),
  refining the target from every vector (on the line, as far as the part of the plate in
  view tells); arrived when stopped within the docking tolerances.

``planner="dwa"`` replaces the arc planner on the navigation field by the dynamic window
approach (:mod:`agent.control.dwa`) toward the goal (or the docking line's start), with the
same safety rule, the same final approaches, parking turn and docking line. The controller
never gives up while time remains (mode ``"failed"`` is not used: the task's time limit is
the evaluation's to apply).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from agent.arrays import FloatArray
from agent.control import (
    clearance_kernels,
    geometry_kernels,
    navigation_kernels,
    obstacles_kernels,
)
from agent.control.clearance import ClearanceMap, LocalState, max_scale
from agent.control.docking import (
    DockTarget,
    LineState,
    dock_pose,
    find_dock_target,
    line_clearance,
    line_command,
    line_state,
    refine_face,
    search_viewpoint,
)
from agent.control.dwa import DynamicWindowPlanner
from agent.control.geometry import outline_perimeter, roll_out, sweep_points, wrap_angle
from agent.control.give_way import Walkers, WayOut, walk_danger, way_out
from agent.control.landmarks import DriftEstimate
from agent.control.local_planner import ArcPlanner, Plan
from agent.control.navigation import NavigationField
from agent.control.obstacles import Capsules, capsules_from_view
from agent.control.settings import ControllerSettings
from agent.control.view import EnvironmentView, unusable_reason
from agent.control.walk_lines import movers_on_lines
from agent.control.walkways import WalkwayMemory
from agent.kinematics.vehicle import VehicleSpec
from agent.task import Task

__all__ = [
    "PLANNERS",
    "ControlOutput",
    "Controller",
    "ControllerSettings",
    "EnvironmentView",
    "PlannerName",
    "warm_up",
]

PlannerName = Literal["default", "dwa"]
PLANNERS: tuple[PlannerName, ...] = ("default", "dwa")

_HISTORY = 256  # odometry samples kept: 5 s at 50 Hz, for the pose at a vector's stamp
_STOPPED_M_S = 1e-3  # measured speed (and rad/s) below which the vehicle has stopped
# The memory's clock runs while the odometry's speed or yaw rate exceeds these (1 cm/s at the
# outline's corners, 0.5 m out): :mod:`agent.control.memory_clock`.
_MOVING_M_S, _MOVING_RAD_S = 0.01, 0.02
_ROTATE_RAD_S = 1.0  # turning on the spot
_FACE_RAD = 0.6  # a point approach turns on the spot first when the goal is further off
_STUCK_S = 1.5  # navigating without progress this long: the planner must move (unstick),
# until the vehicle has moved 0.15 m or turned 0.5 rad, or for 3 s
_GOAL_MOVE_M = 0.03  # the goal follows the drift estimate in steps larger than this
_VIEWPOINT_REACH_M = 0.2  # a place to search the docking target from: reached within this
_LOOK_AFTER_S = 4.5  # no progress for this long (unsticking did not help): look
_PROGRESS_M, _PROGRESS_RAD = 0.1, 0.3  # progress: this far, or this much turn
_FACE_WAY_RAD = 0.45  # the way ahead further off the heading than this: turn to face it
_FACED_RAD = 0.1  # ... until it is this near
_WAY_AHEAD_M = 1.2  # the way ahead: the field's path this far on
_FACE_AGAIN_S = 3.0  # after a facing turn (done, or blocked both ways), not again for this
_SAME_TURN_RAD = 0.1  # turns toward headings this near, from places this near, for at
_SAME_PLACE_M = 0.05  # most this long, are one turn (a way found blocked stays so)
_TURN_BLOCKED_S = 5.0
_ALIGN_KEEP = 2.5  # turning onto the docking line goes on within this × where it began
_RETREAT_M = 0.3  # a retreat on the docking line backs off until this short of the stop
_REFINE_TURN_RAD = math.radians(5.0)  # on the docking line, a face that turns by more ...
_REFINE_SHIFT_M = 0.05  # ... or moves by more along its normal is not taken
_REFINE_SLIDE_M = 0.08  # its centre moves along it by no more (a face at least as long)
_REFINE_UNTIL_M = 0.4  # for the last this of the line, only the face's offset is refined
_EMPTY = np.zeros((0, 2))
_EMPTY.flags.writeable = False


@dataclass(frozen=True)
class ControlOutput:
    """One command and what the controller is doing.

    Attributes
    ----------
    speed_m_s, yaw_rate_rad_s
        The twist to send (base_link; m/s, rad/s counter-clockwise).
    intent_xy
        (p, 2) ``odom``: the path the controller intends to drive, nearest first (a few
        waypoints over about 2 m), for the agent's sensor planner; empty once arrived.
    mode
        ``"waiting"``, ``"driving"``, ``"escaping"``, ``"parking"``, ``"docking"`` or
        ``"arrived"``.
    reason
        Why it stops or slows: ``"no_odometry"``, ``"no_environment"``,
        ``"stale_environment"``, ``"sensor_not_ok"``, ``"yielding"``, ``"giving_way"``
        (moving out of a coming walker's walk), ``"blocked"``,
        ``"unknown_ahead"``, ``"searching"`` (no docking target seen yet), ``"stopping"``,
        ``"looking"`` (turning on the spot to see about it), ``"backing"`` (backing off
        before it looks, to see the space just ahead), ``"facing"`` (turning on the
        spot to face the way ahead); ``""`` when nothing to say.
    arrived
        The task is done and the vehicle stands still.
    """

    speed_m_s: float
    yaw_rate_rad_s: float
    intent_xy: FloatArray
    mode: str
    reason: str
    arrived: bool


@dataclass
class _Turning:
    """A turn on the spot: toward ``yaw`` from ``xy``, begun at ``since_s``; the ways
    (+1 left, -1 right) found blocked."""

    yaw: float
    xy: FloatArray
    since_s: float
    blocked: set[float]


def warm_up() -> None:
    """Load the controller's compiled kernels (compiling them on the first use on a
    machine), so that the first vector and command of a process do not."""
    clearance_kernels.warm_up()
    geometry_kernels.warm_up()
    navigation_kernels.warm_up()
    obstacles_kernels.warm_up()


def _walkers(
    view: EnvironmentView, capsules: Capsules, velocity: FloatArray, memory: WalkwayMemory
) -> Walkers:
    """The vector's movers (``capsules``, from :func:`capsules_from_view`, with their
    ``velocity`` (k, 2)) and the ones ``memory`` keeps on their walks after they left it,
    as walkers at the vector's stamp."""
    moving = capsules.moving
    kept = memory.walkers
    # How far each walks on before it may turn back (where its velocity agrees with the way
    # its walk shows it walking) and where its walk ends, along ``v``
    # (:attr:`WalkwayMemory.ends`).
    onward = np.zeros(int(moving.sum()))
    span = np.tile([-np.inf, np.inf], (onward.size, 1))
    for j, (i, v) in enumerate(zip(capsules.obstacle_id[moving].tolist(), velocity[moving],
                                   strict=True)):  # fmt: skip
        ends = memory.ends.get(i)
        if ends is None:
            continue
        heading, on, lo, hi = ends
        along = float(heading @ v)
        if along > 0.0:
            onward[j] = on
        span[j] = (lo, hi) if along >= 0.0 else (-hi, -lo)
    return Walkers(
        np.concatenate([np.asarray(view.position_xy, dtype=np.float64)[moving], kept.position]),
        np.concatenate([velocity[moving], kept.velocity]),
        np.concatenate([capsules.radius[moving], kept.radius]),
        np.concatenate([np.zeros(int(moving.sum())), kept.age]),
        view.stamp_s,
        np.concatenate([onward, kept.onward_m]),
        np.concatenate([span, kept.span_m]),
    )


def _near_line_start(
    pose: FloatArray,
    start: FloatArray,
    end: FloatArray,
    line: LineState,
    settings: ControllerSettings,
    scale: float,
) -> bool:
    """Whether base_link stands near enough the docking line's start to turn onto the line
    where it is: within ``scale`` × ``dock_align_cross_m`` across the line and ``scale`` ×
    ``dock_align_along_m`` along it from the start (the line follower takes up what is
    left across). Entered at 1, left beyond a wider ``scale``: the target's estimate moves
    as more of its face is seen, the line with it."""
    u = np.array([math.cos(float(end[2])), math.sin(float(end[2]))])
    along = float((pose[:2] - start) @ u)
    return (
        abs(line.cross_m) <= scale * settings.dock_align_cross_m
        and abs(along) <= scale * settings.dock_align_along_m
    )


def _stop(mode: str, reason: str, intent: FloatArray | None = None) -> ControlOutput:
    empty = np.zeros((0, 2))
    return ControlOutput(0.0, 0.0, empty if intent is None else intent, mode, reason, False)


class Controller:
    """The vehicle controller (module docstring).

    Parameters
    ----------
    task
        What to do; the goal in the world frame (= ``odom`` at the start).
    spec
        The vehicle's outline and limits.
    settings
        The controller's constants (:class:`ControllerSettings` by default).
    planner
        ``"default"`` (arcs on the navigation field) or ``"dwa"`` (the dynamic window
        baseline).

    Raises
    ------
    ValueError
        For an unknown planner, and (from the update methods) for malformed input.
    """

    def __init__(
        self,
        task: Task,
        spec: VehicleSpec | None = None,
        settings: ControllerSettings | None = None,
        planner: PlannerName = "default",
    ) -> None:
        if planner not in PLANNERS:
            raise ValueError(f"Controller: planner must be one of {PLANNERS}, got {planner!r}")
        self.task = task
        self.spec = spec if spec is not None else VehicleSpec()
        self.settings = settings if settings is not None else ControllerSettings()
        self.planner: PlannerName = planner
        self.goal_xy = np.array(task.goal, dtype=np.float64)  # in ``odom`` (drift carried)
        self._drift = DriftEstimate()
        self._clearance = ClearanceMap(self.spec, self.settings)
        self._walkways = WalkwayMemory(self.spec, self.settings)
        self._field = NavigationField(self.spec, self.settings)
        self._arcs = ArcPlanner(self.spec, self.settings) if planner == "default" else None
        self._dwa = DynamicWindowPlanner(self.spec, self.settings) if planner == "dwa" else None
        self._odometry = np.zeros((2 * _HISTORY, 6))  # t, x, y, yaw (unwrapped), v, w
        self._count = 0
        self._view: EnvironmentView | None = None
        self._pending = False
        self._capsules: Capsules | None = None
        self._walkers = Walkers.none()
        self.watch_xy: FloatArray = np.zeros((0, 2))  # places to look at (``_ingest``)
        self._intent: FloatArray = np.zeros((0, 2))  # the last way it meant to drive
        self._outline = outline_perimeter(self.spec, self.settings.outline_spacing_m)
        self._local: LocalState | None = None
        self._last_twist = (0.0, 0.0)
        self._last_call_s: float | None = None
        self._arrived = False
        self._phase = "navigate"
        self._target: DockTarget | None = None
        self._searching_since: float | None = None  # facing the dock's goal, nothing seen
        self._search_closer = False  # ... for dock_search_wait_s: search from nearer
        self._searched: list[FloatArray] = []  # places searched from, nothing seen (odom)
        self._viewpoint: FloatArray | None = None  # the next place to search from
        self._viewpoint_s = -math.inf  # ... chosen then
        self._moved_s = -math.inf  # when the vehicle last made progress, or had no cause to
        self._progress_pose: FloatArray | None = None  # where it was then
        self._unstick_from: tuple[FloatArray, float] | None = None
        self._unstuck_for = -math.inf  # the spell without progress unsticking was tried in
        self._looked_elsewhere_s = -math.inf
        self._window_stated_s = -math.inf
        self._started = False  # whether navigating has begun (and the start's look with it)
        self._look: list[float] = []  # headings (odom, rad) still to turn to, in order
        self._back_from: FloatArray | None = None  # backing off from here before looking
        self._stand_until: float | None = None  # standing while the head looks, until
        self._then_look: list[float] = []  # the turn round to make if the head did not pan
        self._then_face: float | None = None  # then the way ahead to face (after backing)
        self._head_panned_s = -math.inf  # the newest vector whose scan was off the heading
        self._face_yaw: float | None = None  # turning on the spot to face this way
        self._face_again_s = -math.inf  # no facing turn before this (one just ended)
        self._turning: _Turning | None = None  # the last turn on the spot
        # The ring a turn on the spot sweeps (about the base's origin): the corners' circle,
        # less a cell, in points 0.15 m apart (the head's planner takes each cell's
        # neighbours with it).
        radius = self.spec.circumradius_m - 0.05
        angles = np.linspace(0.0, 2.0 * math.pi, math.ceil(2.0 * math.pi * radius / 0.15),
                             endpoint=False)  # fmt: skip
        self._ring = radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)

    # ------------------------------------------------------------------ inputs
    def update_odometry(
        self,
        t_s: float,
        pose: FloatArray,
        covariance: FloatArray,
        speed_m_s: float,
        yaw_rate_rad_s: float,
    ) -> None:
        """The base's odometry at ``t_s``: ``pose`` (3,) x, y (m), yaw (rad) of base_link in
        ``odom``; ``covariance`` (3, 3) over it (unused: the controller plans in ``odom``,
        where its obstacles are too); the measured twist. Older than the newest: ignored.

        Raises
        ------
        ValueError
            For wrong shapes or non-finite values.
        """
        p = np.asarray(pose, dtype=np.float64)
        if p.shape != (3,) or np.shape(covariance) != (3, 3):
            raise ValueError(
                f"update_odometry: pose must be (3,) and covariance (3, 3), got {p.shape} "
                f"and {np.shape(covariance)}"
            )
        values = (t_s, *p.tolist(), speed_m_s, yaw_rate_rad_s)
        if not all(math.isfinite(v) for v in values):
            raise ValueError("update_odometry: time, pose and twist must be finite")
        n = self._count
        if n and t_s <= self._odometry[n - 1, 0]:
            return
        if n == self._odometry.shape[0]:
            self._odometry[:_HISTORY] = self._odometry[n - _HISTORY : n]
            n = self._count = _HISTORY
        yaw = p[2]
        if n:  # unwrap, so that interpolation never turns the long way
            yaw = self._odometry[n - 1, 3] + float(wrap_angle(yaw - self._odometry[n - 1, 3]))
        self._odometry[n] = (t_s, p[0], p[1], yaw, speed_m_s, yaw_rate_rad_s)
        self._count = n + 1
        self._clearance.clock.update(
            t_s, abs(speed_m_s) > _MOVING_M_S or abs(yaw_rate_rad_s) > _MOVING_RAD_S
        )
        self._clearance.drift.update(t_s, float(p[0]), float(p[1]), float(yaw))
        if n == 0:  # the start: the world keeps this much clear about the vehicle
            self._clearance.add_disc(
                t_s, p[:2], self.spec.circumradius_m + self.settings.start_clear_m
            )
        if self._pending:
            self._ingest()

    def update_environment(self, view: EnvironmentView) -> None:
        """An environment vector. One stamped before the newest is ignored; the newest is
        the one :meth:`command` judges."""
        if self._view is not None and view.stamp_s < self._view.stamp_s:
            return
        self._view = view
        self._local = None
        self._pending = bool(view.sensor_ok)
        if self._pending and self._count:
            self._ingest()

    def _ingest(self) -> None:
        """Put the newest vector into the memory, the field and the local state."""
        view = self._view
        assert view is not None
        self._pending = False
        at_stamp = self._pose_at(view.stamp_s)
        latest = self._odometry[self._count - 1]
        pose_now = latest[1:4].copy()
        st = self.settings
        capsules = capsules_from_view(view, st)
        if st.correct_drift:
            # The world's goal where the odometry's drift now puts it (:mod:`.landmarks`),
            # moved only by more than a cell (each move refits the navigation field).
            self._drift.update(view, capsules.moving, at_stamp)
            goal = self._drift.to_odom(np.array(self.task.goal, dtype=np.float64))
            if float(np.hypot(*(goal - self.goal_xy))) > _GOAL_MOVE_M:
                self.goal_xy = goal
        remembered = self._walkways.update(view, capsules, at_stamp)
        # Movers along the lines their trails show (:mod:`agent.control.walk_lines`).
        capsules, velocity = movers_on_lines(
            capsules, view.velocity_xy, view.covariance, self._walkways.lines,
            st.mover_horizon_s, st.covariance_sigmas, st.mover_inflation_cap_m,
            st.obstacle_margin_m, self._walkways.turns,
        )  # fmt: skip
        self._walkers = _walkers(view, capsules, velocity, self._walkways)
        # Where the walkers it remembers may be: for the head to look (a walker found is
        # tracked again, a walk seen empty is freed).
        self.watch_xy = self._walkways.possible_places(
            at_stamp[:2], st.watch_reach_m, st.watch_points
        )
        # Where it will turn on the spot (a park's goal, the docking line's start): the
        # ring its corners sweep, for the head to look at while it comes (from there, the
        # ring's cells beside the body lie nearer the head than its near limit).
        turn_at = self._turn_place()
        if turn_at is not None and float(np.hypot(*(turn_at - at_stamp[:2]))) <= st.turn_watch_m:
            self.watch_xy = np.concatenate([self.watch_xy, turn_at + self._ring])
        capsules = capsules.joined(remembered)
        self._capsules = capsules
        # Did the head look outside the forward window? (Lit sectors well beyond it, more
        # than the vehicle's own turn in the agent's 0.5 s of memory explains.)
        turned = abs(float(wrap_angle(at_stamp[2] - self._pose_at(view.stamp_s - 0.5)[2])))
        lit = (view.far_or_range_m >= self.settings.near_limit_m) & (
            np.abs(view.free_bearing_rad) > self.settings.looked_elsewhere_rad + turned
        )
        if lit.any():
            self._looked_elsewhere_s = view.stamp_s
        # An agent that states its scanned windows (``scan_window_rad``) and stated none for
        # this vector did not know where its beams went (an older filter, the head
        # slewing): no silence is read then, not a guess.
        if view.scan_window_rad.size == 2:
            self._window_stated_s = view.stamp_s
            centre = 0.5 * float(view.scan_window_rad[0] + view.scan_window_rad[1])
            if abs(centre) >= self.settings.head_panned_rad:
                self._head_panned_s = view.stamp_s
        states_windows = view.stamp_s - self._window_stated_s <= 2.0
        self._clearance.window_scanned = (
            not states_windows and view.stamp_s - self._looked_elsewhere_s > 2.0
        )
        self._clearance.add_profile(view, at_stamp, capsules)
        self._clearance.add_footprint(float(latest[0]), pose_now)
        if self.task.kind == "dock":
            # Taken whole until the last approach begins; on the line, refined as far as
            # the part of the plate in view tells (:func:`refine_face`, the module
            # docstring of :mod:`agent.control.docking`).
            target = find_dock_target(
                view, self.goal_xy, self.settings.dock_search_m, pose_now[:2], self._target
            )
            if target is not None and self._phase not in ("final", "retreat"):
                self._target = target
            elif target is not None and self._target is not None:
                to_go = line_state(pose_now, self._dock_end(), self.spec.head_offset_m).to_go_m
                self._target = refine_face(
                    self._target, target, _REFINE_TURN_RAD, _REFINE_SHIFT_M, _REFINE_SLIDE_M,
                    hold_line=to_go <= _REFINE_UNTIL_M,
                )  # fmt: skip
        if self.planner == "default":
            goal = self._nav_goal(pose_now)[0]
            if not (self._field.covers(pose_now[:2], 1.5) and self._field.covers(goal, 0.5)):
                self._field.fit(pose_now[:2], goal)
            self._field.add_view(view, at_stamp, capsules)
        self._local = self._clearance.compose(
            float(latest[0]), pose_now, capsules, self._head_pans(view.stamp_s)
        )

    def _head_pans(self, t_s: float) -> bool:
        """Whether the agent's head pans: a vector's scanned window lay off the heading
        within ``head_pans_memory_s`` of ``t_s``."""
        return t_s - self._head_panned_s <= self.settings.head_pans_memory_s

    def _pose_at(self, t_s: float) -> FloatArray:
        """The odometry's pose (3,) at ``t_s``: interpolated within the history, advanced
        along the newest twist (at most 0.5 s) after it, the oldest before it."""
        h = self._odometry[: self._count]
        if t_s >= h[-1, 0]:
            t, x, y, yaw, v, w = h[-1]
            dt = min(t_s - t, 0.5)
            if abs(w) < 1e-9:
                return np.array([x + v * dt * math.cos(yaw), y + v * dt * math.sin(yaw), yaw])
            yaw2 = yaw + w * dt
            return np.array(
                [x + v / w * (math.sin(yaw2) - math.sin(yaw)),
                 y - v / w * (math.cos(yaw2) - math.cos(yaw)), yaw2]
            )  # fmt: skip
        if t_s <= h[0, 0]:
            return h[0, 1:4].copy()
        i = int(np.searchsorted(h[:, 0], t_s))
        f = (t_s - h[i - 1, 0]) / (h[i, 0] - h[i - 1, 0])
        return np.asarray(h[i - 1, 1:4] + f * (h[i, 1:4] - h[i - 1, 1:4]), dtype=np.float64)

    # ------------------------------------------------------------------ the command
    def command(self, now_s: float) -> ControlOutput:
        """The twist to send at ``now_s`` (module docstring)."""
        st = self.settings
        interval = st.period_s if self._last_call_s is None else now_s - self._last_call_s
        self._last_call_s = now_s
        dt = min(max(interval, st.period_s), 0.5)
        tau = dt + st.latency_s
        if not self._count:
            return self._send(_stop("waiting", "no_odometry"), now_s)
        reason = unusable_reason(self._view, now_s)
        if reason:
            return self._send(_stop("waiting", reason), now_s)
        if self._pending:
            self._ingest()
        pose = self._pose_at(now_s)
        if self._local is None:
            assert self._capsules is not None
            self._local = self._clearance.compose(
                now_s, pose, self._capsules, self._head_pans(now_s)
            )
        if self._arrived:
            return self._send(ControlOutput(0.0, 0.0, _EMPTY, "arrived", "", True), now_s)
        mode = {"goto": "driving", "park": "parking", "dock": "docking"}[self.task.kind]
        if self._local.mover_intrudes:
            return self._send(self._give_way(pose, now_s, dt, tau, mode), now_s)
        if len(self._walkers) and self._in_danger(pose, now_s):
            way = self._way_out(pose, now_s)  # out of the walk before its walker may come
            if way is not None:
                return self._send(self._leave_walk(pose, way, dt, tau, mode), now_s)
        if self.task.kind == "dock":
            out = self._dock(pose, now_s, dt, tau)
        elif self.task.kind == "park":
            out = self._park(pose, now_s, dt, tau)
        else:
            out = self._goto(pose, now_s, dt, tau)
        return self._send(out, now_s)

    def _send(self, out: ControlOutput, now_s: float) -> ControlOutput:
        self._last_twist = (out.speed_m_s, out.yaw_rate_rad_s)
        if out.intent_xy.size and out.reason != "yielding":
            self._intent = out.intent_xy
        # Progress: 0.1 m or 0.3 rad since the last mark (creeping to and fro, or a turn
        # begun each way in turn, is none), or no cause to move.
        pose = self._odometry[self._count - 1, 1:4]
        if self._progress_pose is None or (
            float(np.hypot(*(pose[:2] - self._progress_pose[:2]))) > _PROGRESS_M
            or abs(float(wrap_angle(pose[2] - self._progress_pose[2]))) > _PROGRESS_RAD
            or out.mode in ("waiting", "arrived")
            or out.reason in ("yielding", "giving_way", "stopping")
        ):
            self._progress_pose = pose.copy()
            self._moved_s = now_s
        return out

    def _give_way(
        self, pose: FloatArray, now_s: float, dt: float, tau: float, mode: str
    ) -> ControlOutput:
        """A mover's capsule reaches the vehicle: out of the walk of a walker that comes,
        if it can be left in time, else stand (:mod:`agent.control.give_way`)."""
        way = self._way_out(pose, now_s)
        if way is None:
            # Standing, it still means to go its way: the head is to look along it (where
            # the walker it waits for may be), not only ahead.
            return _stop(mode, "yielding", self._intent)
        return self._leave_walk(pose, way, dt, tau, mode)

    def _in_danger(self, pose: FloatArray, now_s: float) -> bool:
        """Whether the outline stands in a walk whose walker may come before the vehicle,
        ``give_way_lead_s`` from now, could leave it (:func:`walk_danger`)."""
        here = sweep_points(pose, self._outline)
        walkers = self._walkers.at(now_s)
        lead = self.settings.give_way_lead_s
        return bool(walk_danger(here, walkers, self.spec, self.settings, lead) > 0.0)

    def _way_out(self, pose: FloatArray, now_s: float) -> WayOut | None:
        assert self._local is not None
        return way_out(
            pose, self._outline, self._walkers.at(now_s), self._local, self.spec, self.settings
        )

    def _leave_walk(
        self, pose: FloatArray, way: WayOut, dt: float, tau: float, mode: str
    ) -> ControlOutput:
        intent = roll_out(pose, way.v_unit, way.w_unit, way.distance_m, 4)
        return self._drive(
            pose, way.speed_m_s, way.yaw_rate_rad_s, dt, tau, mode, "giving_way", intent
        )

    def _stopped(self) -> bool:
        """Whether the vehicle stands still: the last command and the newest odometry."""
        v, w = self._odometry[self._count - 1, 4:6]
        return self._last_twist == (0.0, 0.0) and abs(v) < _STOPPED_M_S and abs(w) < _STOPPED_M_S

    def _arrive(self, mode: str) -> ControlOutput:
        """Stop; arrived once the vehicle stands still."""
        if self._stopped():
            self._arrived = True
            return ControlOutput(0.0, 0.0, np.zeros((0, 2)), "arrived", "", True)
        return _stop(mode, "stopping")

    # ------------------------------------------------------------------ moving safely
    def _drive(
        self,
        pose: FloatArray,
        v: float,
        w: float,
        dt: float,
        tau: float,
        mode: str,
        reason: str,
        intent: FloatArray,
        local: LocalState | None = None,
    ) -> ControlOutput:
        """Ramp from the last command toward ``(v, w)`` within the acceleration limits over
        ``dt``, then scale it down to what the braking envelope allows (in ``local``, the
        known clear space now unless given)."""
        spec = self.spec
        v0, w0 = self._last_twist
        v = max(-spec.max_speed_m_s, min(spec.max_speed_m_s, v))
        w = max(-spec.max_yaw_rate_rad_s, min(spec.max_yaw_rate_rad_s, w))
        # Along the straight line from the last twist to the wanted one, as far as both
        # limits allow: from rest, the wanted arc's own curvature.
        dv, dw = abs(v - v0), abs(w - w0)
        step = min(
            1.0,
            spec.max_accel_m_s2 * dt / dv if dv > 0.0 else 1.0,
            spec.max_yaw_accel_rad_s2 * dt / dw if dw > 0.0 else 1.0,
        )
        v, w = v0 + step * (v - v0), w0 + step * (w - w0)
        lam = self._admissible_scale(pose, v, w, tau, local)
        if lam < 1.0:
            v, w = v * lam, w * lam
            if not reason:
                reason = "blocked" if lam == 0.0 else "unknown_ahead"
        if abs(v) < 1e-4 and abs(w) < 1e-4:
            v = w = 0.0
        return ControlOutput(v, w, intent, mode, reason, False)

    def _admissible_scale(
        self, pose: FloatArray, v: float, w: float, tau: float, local: LocalState | None = None
    ) -> float:
        """The largest λ in [0, 1] for which λ·(v, w) is admissible now (in ``local``, the
        known clear space now unless given)."""
        if v == 0.0 and w == 0.0:
            return 1.0
        local = self._local if local is None else local
        assert local is not None
        st = self.settings
        d_free = local.free_travel(pose, np.array([v]), np.array([w]))
        lam = max_scale(np.array([v]), np.array([w]), d_free, self.spec, tau, st.stop_margin_m)
        return float(lam[0])

    # ------------------------------------------------------------------ navigation
    def _nav_goal(self, pose: FloatArray) -> tuple[FloatArray, float]:
        """Where the planners head for now: (point, radius)."""
        if self.task.kind != "dock":
            return self.goal_xy, 0.0
        if self._target is None:
            if self._viewpoint is not None:
                return self._viewpoint, _VIEWPOINT_REACH_M
            return self.goal_xy, self._search_radius()
        return self._dock_start(), 0.0

    def _turn_place(self) -> FloatArray | None:
        """Where the task will have the vehicle turn on the spot, if it knows yet."""
        if self._arrived:
            return None
        if self.task.kind == "park":
            return self.goal_xy
        if self.task.kind == "dock" and self._target is not None:
            return self._dock_start()
        return None

    def _search_radius(self) -> float:
        """How near the goal the vehicle searches for the docking target: from 0.6 m beyond
        the docking pose's distance, then (nothing seen there) from that distance."""
        closer = 0.0 if self._search_closer else 0.6
        return self.task.dock_distance_m + self.spec.head_offset_m + closer

    def _search_elsewhere(self, pose: FloatArray, now_s: float) -> None:
        """Nothing seen from here: choose the next place to search from
        (:func:`~agent.control.docking.search_viewpoint`), starting over once every side
        was tried."""
        self._searched.append(pose[:2].copy())
        self._search_closer = False
        caps = self._capsules
        static = caps.select(~caps.moving) if caps is not None else None
        obstacles = (
            (static.a, static.b, static.reach) if static is not None
            else (np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
        )  # fmt: skip
        radius = self._search_radius()  # the far one, from there
        keep = self.spec.circumradius_m
        place = search_viewpoint(
            self.goal_xy, radius, np.array(self._searched), pose[:2], obstacles, keep
        )
        if place is None and len(self._searched) > 1:  # every side tried: again
            self._searched = [pose[:2].copy()]
            place = search_viewpoint(
                self.goal_xy, radius, np.array(self._searched), pose[:2], obstacles, keep
            )
        self._viewpoint, self._viewpoint_s = place, now_s

    def _dock_end(self) -> FloatArray:
        """The docking pose (3,) ``odom`` of the target held now."""
        assert self._target is not None
        return dock_pose(self._target, self.task.dock_distance_m, self.spec.head_offset_m)

    def _dock_start(self) -> FloatArray:
        end = self._dock_end()
        u = np.array([math.cos(end[2]), math.sin(end[2])])
        return np.asarray(end[:2] - self.settings.dock_line_m * u, dtype=np.float64)

    def _navigate(
        self,
        pose: FloatArray,
        now_s: float,
        goal_xy: FloatArray,
        radius_m: float,
        dt: float,
        tau: float,
        mode: str,
    ) -> ControlOutput:
        """Drive toward ``goal_xy`` (within ``radius_m``) with the planner; when it makes
        no progress, look first (:meth:`_looking`)."""
        assert self._local is not None
        look = self._looking(pose, now_s, goal_xy, dt, tau, mode)
        if look is not None:
            return look
        plan: Plan
        if self._arcs is not None:
            self._update_field(pose, now_s, goal_xy, radius_m)
            # Once in each spell without progress, the planner must move (unstick).
            if (
                self._unstick_from is None
                and now_s - self._moved_s > _STUCK_S
                and self._unstuck_for != self._moved_s
            ):
                self._unstick_from = (pose.copy(), now_s)
                self._unstuck_for = self._moved_s
            if self._unstick_from is not None:
                start, since = self._unstick_from
                moved = float(np.hypot(*(pose[:2] - start[:2])))
                turned = abs(float(wrap_angle(pose[2] - start[2])))
                if moved > 0.15 or turned > 0.5 or now_s - since > 3.0:
                    self._unstick_from = None
            unstick = self._unstick_from is not None
            face = None if unstick else self._face_the_way(pose, now_s, dt, tau, mode)
            if face is not None:
                return face
            plan = self._arcs.choose(
                pose, self._local, self._field, tau, unstick=unstick,
                walkers=self._walkers.at(now_s),
            )  # fmt: skip
            tail = self._field.path(
                plan.rollout_xy[-1] if len(plan.rollout_xy) else pose[:2], 2.0, 0.3
            )
            intent = np.concatenate([plan.rollout_xy, tail])[:10]
            descent = float(self._field.descent(pose[None, :2])[0])
            to_goal = math.atan2(goal_xy[1] - pose[1], goal_xy[0] - pose[0])
            if mode == "driving" and abs(float(wrap_angle(descent - to_goal))) > 0.5 * math.pi:
                mode = "escaping"
        else:
            assert self._dwa is not None
            v0, w0 = self._last_twist
            plan = self._dwa.choose(pose, self._local, goal_xy, v0, w0, dt, tau)
            intent = np.concatenate([plan.rollout_xy, goal_xy[None]])
        return self._drive(
            pose, plan.speed_m_s, plan.yaw_rate_rad_s, dt, tau, mode, plan.reason, intent
        )

    def _face_the_way(
        self, pose: FloatArray, now_s: float, dt: float, tau: float, mode: str
    ) -> ControlOutput | None:
        """Turn on the spot to face the way ahead, or ``None``.

        The window sees only within 20° of the heading: a vehicle that drives off the way
        it must go (more than :data:`_FACE_WAY_RAD` from the bearing of the field's path
        :data:`_WAY_AHEAD_M` on) never sees it, and the space its corners would sweep there
        stays unknown. It turns to face the way first (to within :data:`_FACED_RAD`), where
        turning on the spot is admissible; where it is not, the planner goes on.
        """
        if now_s < self._face_again_s:
            return None
        if self._face_yaw is None:
            path = self._field.path(pose[:2], _WAY_AHEAD_M + 0.3, 0.1)
            if len(path) < 2:
                return None
            far = np.hypot(*(path - pose[:2]).T) >= _WAY_AHEAD_M
            point = path[int(np.argmax(far))] if far.any() else path[-1]
            way = math.atan2(point[1] - pose[1], point[0] - pose[0])
            if abs(float(wrap_angle(way - pose[2]))) <= _FACE_WAY_RAD:
                return None
            # Held until faced (or blocked): the field changes as the turn shows more, and
            # a target that moved with it was chased at a crawl.
            self._face_yaw = way
        if abs(float(wrap_angle(self._face_yaw - pose[2]))) <= _FACED_RAD:
            self._face_yaw = None  # faced: the planner's turn, for a while
            self._face_again_s = now_s + _FACE_AGAIN_S
            return None
        out = self._turn(pose, self._face_yaw, now_s, dt, tau, mode)
        if out.yaw_rate_rad_s == 0.0:  # blocked both ways: the planner's turn for a while
            self._face_yaw = None
            self._face_again_s = now_s + _FACE_AGAIN_S
            return None
        return replace(out, reason="facing")

    def _looking(
        self,
        pose: FloatArray,
        now_s: float,
        goal_xy: FloatArray,
        dt: float,
        tau: float,
        mode: str,
        ahead_rad: float | None = None,
    ) -> ControlOutput | None:
        """Look before going: the command while the vehicle turns to see, or ``None``.

        With the head's window fixed ahead, the vehicle's own heading is where it looks.
        The space the front corners pass through on the way ahead lies beside the window
        until 0.85 m out, so after a turn, or at the start, it is unknown and the planner
        finds no way on. At the start (unless ``look_at_start`` is off), and when
        navigating has made less than 0.1 m or 0.3 rad of progress for
        :data:`_LOOK_AFTER_S` (unsticking included), the vehicle backs off
        ``back_off_m`` where it may (the space just ahead of the bumper, nearer than the
        near limit, is seen only from further back), then turns on the spot all round in
        thirds, first toward the way ahead (``ahead_rad`` if given, else the field's
        descent, or the goal's bearing), then to it, each third where that is
        admissible: the window sweeps the corners' paths, which the memory then holds
        while the vehicle drives on.
        """
        st = self.settings
        if not self._started:  # the start: look all round first
            self._started = True
            self._moved_s = now_s
            if st.look_at_start:
                third = 2.0 * math.pi / 3.0
                self._then_look = [pose[2] + third, pose[2] + 2.0 * third, pose[2] + 3.0 * third]
                self._stand_until = now_s + st.look_stand_s
        if not self._look and self._stand_until is None and now_s - self._moved_s >= _LOOK_AFTER_S:
            if ahead_rad is not None:
                ahead = ahead_rad
            elif self._arcs is not None and self._field.cost_to_go is not None:
                ahead = float(self._field.descent(pose[None, :2])[0])
            else:
                ahead = math.atan2(goal_xy[1] - pose[1], goal_xy[0] - pose[0])
            ahead = pose[2] + float(wrap_angle(ahead - pose[2]))
            first = 1.0 if float(wrap_angle(ahead - pose[2])) >= 0.0 else -1.0
            third = 2.0 * math.pi / 3.0
            self._then_look = [pose[2] + first * third, pose[2] + 2 * first * third,
                               pose[2] + 3 * first * third]  # fmt: skip
            self._then_face = ahead
            self._back_from = pose[:2].copy()
            self._stand_until = -math.inf  # set once backed off
        if self._back_from is not None:
            backed = math.hypot(pose[0] - self._back_from[0], pose[1] - self._back_from[1])
            if backed < st.back_off_m:
                out = self._drive(pose, -st.back_off_speed_m_s, 0.0, dt, tau, mode, "", _EMPTY)
                if out.speed_m_s < 0.0:
                    return ControlOutput(out.speed_m_s, 0.0, out.intent_xy, mode, "backing",
                                         False)  # fmt: skip
            self._back_from = None
        if self._stand_until is not None:
            # Stand while the head looks round (a head that pans sees ±110° of the heading
            # from here); turn round only if it did not pan meanwhile (a fixed window).
            if self._stand_until == -math.inf:
                self._stand_until = now_s + st.look_stand_s
            if now_s < self._stand_until:
                intent = self._intent
                if not len(intent):  # the way the head is to look along: toward the goal
                    to_goal = goal_xy - pose[:2]
                    reach = min(float(np.hypot(*to_goal)), 3.0)
                    angle = math.atan2(to_goal[1], to_goal[0])
                    intent = pose[None, :2] + np.outer(
                        [0.5 * reach, reach], [math.cos(angle), math.sin(angle)]
                    )
                out = self._drive(pose, 0.0, 0.0, dt, tau, mode, "", intent)
                return replace(out, reason="looking")
            # A head that pans has looked round: only the way ahead is left to face.
            self._look = [] if self._head_pans(now_s) else self._then_look
            if self._then_face is not None:
                self._look = [*self._look, self._then_face]
            self._then_look, self._then_face = [], None
            self._stand_until = None
            self._moved_s = now_s  # what the look showed: the planner's turn again
        while self._look:
            target = self._look[0]
            if abs(float(wrap_angle(target - pose[2]))) < 0.05:
                self._look.pop(0)
                continue
            out = self._turn(pose, target, now_s, dt, tau, mode)
            if out.yaw_rate_rad_s == 0.0:  # this way is blocked: the next
                self._look.pop(0)
                continue
            return ControlOutput(out.speed_m_s, out.yaw_rate_rad_s, out.intent_xy, mode,
                                 "looking", False)  # fmt: skip
        return None

    def _point_approach(
        self,
        pose: FloatArray,
        goal_xy: FloatArray,
        now_s: float,
        dt: float,
        tau: float,
        mode: str,
    ) -> ControlOutput:
        """Steer straight at ``goal_xy``, slowing to stop on it."""
        spec = self.spec
        dx, dy = goal_xy[0] - pose[0], goal_xy[1] - pose[1]
        d = math.hypot(dx, dy)
        e = float(wrap_angle(math.atan2(dy, dx) - pose[2]))
        if abs(e) > _FACE_RAD and d > 0.02:
            return self._turn(pose, pose[2] + e, now_s, dt, tau, mode)
        v = min(spec.max_speed_m_s, math.sqrt(spec.max_accel_m_s2 * d), d / tau) * math.cos(e)
        w = 0.0 if d < 0.05 else max(-1.0, min(1.0, 2.0 * e)) * spec.max_yaw_rate_rad_s / 1.5
        intent = np.stack([pose[:2], goal_xy])
        return self._drive(pose, v, w, dt, tau, mode, "", intent)

    def _turn(
        self, pose: FloatArray, yaw: float, now_s: float, dt: float, tau: float, mode: str
    ) -> ControlOutput:
        """Turn on the spot toward ``yaw``, slowing to stop on it: the short way, or the
        long way round once the short one is blocked. A way found blocked stays so for
        this turn (the same heading, from the same place, for :data:`_TURN_BLOCKED_S`):
        a turn that went back each time the other way opened by a cell rocked on the spot.
        Blocked both ways, it is refused (zero): the caller is to do something else."""
        spec = self.spec
        e = float(wrap_angle(yaw - pose[2]))
        turning = self._turning
        if (
            turning is None
            or abs(float(wrap_angle(turning.yaw - yaw))) >= _SAME_TURN_RAD
            or float(np.hypot(*(turning.xy - pose[:2]))) > _SAME_PLACE_M
            or now_s - turning.since_s > _TURN_BLOCKED_S
        ):
            turning = self._turning = _Turning(yaw, pose[:2].copy(), now_s, set())
        out = _stop(mode, "blocked")
        for sign in sorted((1.0, -1.0), key=lambda s: s != math.copysign(1.0, e)):
            if sign in turning.blocked:
                continue
            turn = e if math.copysign(1.0, e) == sign else e + sign * 2.0 * math.pi
            rate = min(
                _ROTATE_RAD_S, math.sqrt(spec.max_yaw_accel_rad_s2 * abs(turn)), abs(turn) / tau
            )
            out = self._drive(pose, 0.0, sign * rate, dt, tau, mode, "", _EMPTY)
            if out.yaw_rate_rad_s != 0.0 or abs(turn) < 1e-3:
                return out
            if self._last_twist[1] * sign < 0.0:
                return out  # stopping a turn the other way first: no test of this way
            turning.blocked.add(sign)
        return out

    # ------------------------------------------------------------------ tasks
    def _goto(self, pose: FloatArray, now_s: float, dt: float, tau: float) -> ControlOutput:
        d = float(np.hypot(*(self.goal_xy - pose[:2])))
        if self._reached(d, now_s):
            return self._arrive("driving")
        return self._toward(pose, now_s, self.goal_xy, dt, tau, "driving")

    def _reached(self, d: float, now_s: float) -> bool:
        """Whether a goal ``d`` m off is reached: within ``goal_reach_m`` (at most a third
        of the task's tolerance), or within half the tolerance with no progress for
        :data:`_STUCK_S` (the last centimetres held by unknown space or an obstacle beside
        the goal: the goal's own place in ``odom`` is known to a few tenths of a metre at
        best, and waiting there for the space to clear ran out the time 0.1 m from it,
        within the tolerance in truth; random run 2 of seed 0, no walkers)."""
        tolerance = self.task.tolerance_m
        if d <= min(self.settings.goal_reach_m, tolerance / 3.0):
            return True
        return d <= 0.5 * tolerance and now_s - self._moved_s > _STUCK_S

    def _toward(
        self, pose: FloatArray, now_s: float, goal_xy: FloatArray, dt: float, tau: float, mode: str
    ) -> ControlOutput:
        """To a point: the planner, and the straight approach at the end when nothing the
        field knows stands between (its cost there no more than 1.3 × the distance)."""
        d = float(np.hypot(*(goal_xy - pose[:2])))
        in_sight = True
        if self._arcs is not None:
            self._update_field(pose, now_s, goal_xy, 0.0)
            in_sight = bool(self._field.value(pose[None, :2])[0] <= 1.3 * d + 0.1)
        if d <= self.settings.final_approach_m and in_sight:
            look = self._looking(pose, now_s, goal_xy, dt, tau, mode)
            if look is not None:
                return look
            return self._point_approach(pose, goal_xy, now_s, dt, tau, mode)
        return self._navigate(pose, now_s, goal_xy, 0.0, dt, tau, mode)

    def _update_field(
        self, pose: FloatArray, now_s: float, goal_xy: FloatArray, radius_m: float
    ) -> None:
        if not (self._field.covers(pose[:2], 1.0) and self._field.covers(goal_xy, 0.5)):
            self._field.fit(pose[:2], goal_xy)
        self._field.update(now_s, goal_xy, radius_m, pose[:2])

    def _park(self, pose: FloatArray, now_s: float, dt: float, tau: float) -> ControlOutput:
        task = self.task
        assert task.goal_yaw_rad is not None
        d = float(np.hypot(*(self.goal_xy - pose[:2])))
        if self._phase == "navigate" and self._reached(d, now_s):
            self._phase = "turn"
        if self._phase == "turn" and d > task.tolerance_m / 2.0:
            self._phase = "navigate"
        if self._phase == "navigate":
            return self._toward(pose, now_s, self.goal_xy, dt, tau, "parking")
        yaw_tol = min(self.settings.park_yaw_rad, task.tolerance_rad / 3.0)
        goal_yaw = task.goal_yaw_rad + self._drift.theta  # in ``odom``
        if abs(float(wrap_angle(goal_yaw - pose[2]))) <= yaw_tol:
            return self._arrive("parking")
        return self._turn_there(pose, goal_yaw, now_s, dt, tau, "parking")

    def _turn_there(
        self, pose: FloatArray, yaw: float, now_s: float, dt: float, tau: float, mode: str
    ) -> ControlOutput:
        """Turn on the spot to ``yaw`` where the approach ended (a park's goal, the docking
        line's start). Blocked both ways (unknown space where the corners would sweep,
        beside the body and nearer the head than its near limit, or behind it where no pan
        reaches): back off and look, as when navigating makes no progress, from the next
        command (once stopped); the approach then comes again, straight on. (At the
        docking line's start the turn rocked ±14° every 5 s for 20 s until the time ran
        out: random run 16 of seed 0, no walkers.)"""
        look = self._looking(pose, now_s, self.goal_xy, dt, tau, mode, pose[2])
        if look is not None:
            return look
        out = self._turn(pose, yaw, now_s, dt, tau, mode)
        assert self._turning is not None
        if len(self._turning.blocked) == 2:
            self._moved_s = now_s - _LOOK_AFTER_S
        return out

    def _dock(self, pose: FloatArray, now_s: float, dt: float, tau: float) -> ControlOutput:
        st = self.settings
        if self._target is None:
            # To the next place to search from, until there or given up on; else to within
            # the search radius of the goal (:meth:`_nav_goal`).
            if self._viewpoint is not None and (
                float(np.hypot(*(self._viewpoint - pose[:2]))) <= _VIEWPOINT_REACH_M + 0.1
                or now_s - self._viewpoint_s > st.dock_viewpoint_s
            ):
                self._viewpoint = self._searching_since = None
            toward, radius = self._nav_goal(pose)
            slack = 0.1 if self._viewpoint is not None else 0.2
            if float(np.hypot(*(toward - pose[:2]))) > radius + slack:
                self._searching_since = None
                out = self._navigate(pose, now_s, toward, radius, dt, tau, "docking")
                return replace(out, reason=out.reason or "searching", arrived=False)
            # The goal is the target's place in the world carried into ``odom`` by the
            # drift estimate: off by a metre after a long way (random run 18 of seed 0, no
            # walkers: 1.3 m), the target lay beyond the sensor's reach from 1.4 m, and the
            # vehicle stood facing it to the time limit. Nothing seen for a while, it
            # searches from nearer.
            if self._searching_since is None:
                self._searching_since = now_s
            elif now_s - self._searching_since > st.dock_search_wait_s:
                self._searching_since = None
                if not self._search_closer:
                    self._search_closer = True
                else:  # nothing from this side either: from another (:mod:`.docking`)
                    self._search_elsewhere(pose, now_s)
            bearing = math.atan2(self.goal_xy[1] - pose[1], self.goal_xy[0] - pose[0])
            out = self._turn(pose, bearing, now_s, dt, tau, "docking")
            return ControlOutput(out.speed_m_s, out.yaw_rate_rad_s, out.intent_xy, out.mode,
                                 "searching", False)  # fmt: skip
        end = self._dock_end()
        line = line_state(pose, end, self.spec.head_offset_m)
        start = self._dock_start()
        if self._phase == "final" and (
            abs(line.cross_m) > 0.15 or abs(line.yaw_error_rad) > 0.8
            or line.to_go_m > st.dock_line_m + 0.5
        ):  # fmt: skip
            self._phase = "navigate"
        if self._phase == "retreat" and line.to_go_m >= _RETREAT_M:
            self._phase = "final"
        if self._phase in ("navigate", "align"):
            across = abs(line.cross_m) <= _ALIGN_KEEP * st.dock_align_cross_m
            lined_up = across and abs(line.yaw_error_rad) <= math.radians(3.0)
            if lined_up and 0.0 < line.to_go_m <= st.dock_line_m + 0.5:
                self._phase = "final"
            elif self._phase == "align" or _near_line_start(pose, start, end, line, st, 1.0):
                self._phase = "align"
                if not _near_line_start(pose, start, end, line, st, _ALIGN_KEEP):
                    self._phase = "navigate"
                else:
                    return self._turn_there(pose, float(end[2]), now_s, dt, tau, "docking")
            if self._phase == "navigate":
                return self._toward(pose, now_s, start, dt, tau, "docking")
        intent = np.stack([pose[:2], end[:2]])
        if self._phase == "retreat":  # still short of its mark (above): back along the
            # line, aimed 5 cm past the mark, since the speed toward an aim falls to
            # nothing at it
            aim = line.to_go_m - (_RETREAT_M + 0.05)
            v, w = line_command(replace(line, to_go_m=aim), self.spec, st, tau)
            return self._drive(pose, v, w, dt, tau, "docking", "", intent)
        within = (
            abs(line.head_cross_m) <= st.dock_position_m
            and abs(line.yaw_error_rad) <= st.dock_yaw_rad
        )
        if abs(line.to_go_m) <= st.dock_position_m:
            if within:
                return self._arrive("docking")
            self._phase = "retreat"
            return self._drive(pose, 0.0, 0.0, dt, tau, "docking", "", intent)
        v, w = line_command(line, self.spec, st, tau)
        assert self._local is not None
        return self._drive(
            pose, v, w, dt, tau, "docking", "", intent,
            line_clearance(self._local, self.spec, st, self.task.dock_distance_m),
        )  # fmt: skip
