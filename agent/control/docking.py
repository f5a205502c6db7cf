"""Docking: the target in the environment vector, the pose to stop at, the last approach.

**The target** is the docking target (kind 4) of the vector nearest the task's goal, no
further than ``dock_search_m`` from it: the goal is only where a dock database says the
target is. Its face is the segment between its end points, its centre ``c`` the reference
point; of the face's two normals, ``n`` is the one toward the vehicle (kept from vector to
vector once chosen). It is refined from every vector: the target's place relative to the
vehicle at each scan carries no odometry drift, only the motion since the scan does.

**On the line** (:func:`refine_face`) the face's direction and its offset along its normal
are still refined from every vector, and its centre along the face only from a vector
that gives about as much of the face (its length, less 5 cm) and moves it by 8 cm at
most: from 0.5 m the window sees only part of the plate, and a centre taken from the part
seen moved 0.12 m along the face at the stop and sent the vehicle round to the line's
start again (random run 1 of seed 0, no walkers). Held whole from the line's start, the
target carried the odometry's drift over the approach: in the demo (lock-step, seed 0)
the vehicle stopped 51.6 mm and 2.1° off; with the face's direction refined, still 33 mm
along the face: the line had been entered on 0.23 m of the 0.4 m plate, and the vectors
on the line gave all of it, its centre 34-47 mm along. For the last ``0.4 m`` only the
offset is refined (the wheels' scale error over the approach, 1-2 %, is millimetres along
the line), the direction and the centre held: their jitter of a few millimetres and
tenths of a degree from vector to vector failed the stop's test (1.5 mm, 0.2°), and the
line follower, ω = 10 /m, needs about 0.4 m to take up a turn of the line. A face that
turns by more than 5°, moves 5 cm along its normal or lies along the line beyond 8 cm and
half the face's length is not taken; one under a new track id is (the tracker may give
the plate a new track: in random run 95, 3° off the held face, it was never taken while
the id had to match).

**The pose.** The head's centre of scanning at ``D = c + d·n`` (``d`` = ``dock_distance_m``),
the vehicle facing the face, heading ``φ = atan2(−n)``; base_link at ``B = D + L·n`` with
``L`` the head's offset.

**The last approach** follows the line through ``B`` along ``u = −n`` for ``dock_line_m``.
The vehicle comes onto the line near its start, turning on the spot where it stands
(the controller, ``dock_align_cross_m`` and ``dock_align_along_m``).
With ``e`` the cross-track error of base_link (left of the line positive) and ``e_θ`` the
heading error, per metre driven ``de/ds = sin e_θ`` and ``de_θ/ds = κ``; the curvature

    κ = −ω²·e − 2ω·sin e_θ,    ω = ``dock_gain_per_m``,    ``w = |v|·κ``

makes the errors decay critically damped as ``(1 + ωs)·e^{−ωs}`` (ω = 10 /m leaves 1.7 %
of an error after 0.6 m); reversing (``de/ds = −sin e_θ`` per metre backed), ``κ = ω²·e −
2ω·sin e_θ`` keeps it so. The speed
toward the stop ``g`` ahead of the head (along the line) is

    v = min(v_dock, √(a·g), g/τ)

the last term reaching the stop without overshoot when a command is held ``τ`` (period plus
latency): each period covers at most what is left. The vehicle stops there when head
position (along and across) and heading are within ``dock_position_m`` and ``dock_yaw_rad``;
at the line's end but outside them, it backs off along the line and tries again.

**Unknown space ahead.** With a head that pans, a forward motion keeps the row
``look_ahead_m`` (0.3 m) ahead of the bumper out of unknown cells
(:mod:`agent.control.clearance`). At the stop the bumper is ``d + L`` less half the length
from the face (0.4 m), and the row there lay in the cells next to the face, which the memory
never holds clear (a cell is clear only as far as its far corner lies short of the return;
the face's estimate may lie a few cm behind it): the last approach stopped there for good
(measured in ``evaluate``'s random run 1 of seed 0, no walkers: 7 cm short, 46 s "blocked"
until the time ran out, its true pose within the task's tolerance). On the line the row
stays ``dock_face_gap_m`` short of the face at the stop (:func:`line_clearance`): the space
it guards was seen from the line's start, the head 1.1 m from the face.

**Searching** (:func:`search_viewpoint`). Until the target is seen, the vehicle faces the
goal from where the navigation field brought it, then from nearer; nothing seen, it looks
from another side: a plate on a wall shows its face to one side only, and the field
brings the vehicle to whichever side is cheaper (random run 8 of seed 0, no walkers: the
vehicle faced the back of the plate's wall from the next room for 70 s). The next place
is on the circle of the far search radius about the goal, clear of the obstacles the
vector knows by the vehicle's circumradius, as far round the goal as it can be from
every place already searched (the opposite side first), the nearest to the vehicle among
equals.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from agent.arrays import FloatArray
from agent.control.clearance import LocalState
from agent.control.geometry import point_segment_distance, wrap_angle
from agent.control.settings import ControllerSettings
from agent.control.view import EnvironmentView
from agent.kinematics.vehicle import VehicleSpec
from agent.planning.environment import DOCKING

__all__ = [
    "DockTarget",
    "LineState",
    "dock_pose",
    "find_dock_target",
    "line_clearance",
    "line_command",
    "line_state",
    "refine_face",
    "search_viewpoint",
]


@dataclass(frozen=True)
class DockTarget:
    """A docking target's face (``odom``).

    Attributes
    ----------
    centre_xy
        (2,) m: the face's centre.
    normal_xy
        (2,) unit: the face's normal toward the side the vehicle docks from.
    obstacle_id
        The vector's id of the target.
    length_m
        The face's length as the vector gave it (0: not known).
    """

    centre_xy: FloatArray
    normal_xy: FloatArray
    obstacle_id: int
    length_m: float = 0.0


def find_dock_target(
    view: EnvironmentView,
    goal_xy: FloatArray,
    search_m: float,
    vehicle_xy: FloatArray,
    previous: DockTarget | None = None,
) -> DockTarget | None:
    """The target (module docstring), or ``None`` when no docking target is within
    ``search_m`` of ``goal_xy``. The normal points to the vehicle's side of the face, or
    keeps ``previous``'s side."""
    docking = np.nonzero(view.kind == DOCKING)[0]
    if docking.size == 0:
        return None
    centre = view.position_xy[docking]
    dist = np.hypot(*(centre - goal_xy).T)
    i = int(np.argmin(dist))
    if dist[i] > search_m:
        return None
    k = docking[i]
    a, b = view.extent[k, 0:2], view.extent[k, 2:4]
    along = b - a
    length = float(np.hypot(*along))
    if length <= 0.0:
        return None
    normal = np.array([-along[1], along[0]]) / length
    c = view.position_xy[k].astype(np.float64)
    if previous is not None:
        if float(normal @ previous.normal_xy) < 0.0:
            normal = -normal
    elif float(normal @ (vehicle_xy - c)) < 0.0:
        normal = -normal
    return DockTarget(c, normal, int(view.obstacle_id[k]), length)


def refine_face(
    held: DockTarget,
    fresh: DockTarget,
    max_turn_rad: float,
    max_shift_m: float,
    max_slide_m: float,
    length_tolerance_m: float = 0.05,
    hold_line: bool = False,
) -> DockTarget:
    """``held`` with the face's line of ``fresh`` (its normal, and its offset along it),
    and its centre along the face too where ``fresh`` is at least as long (less
    ``length_tolerance_m``) and moves it along the face by ``max_slide_m`` at most; else
    the centre kept where it lies along the face (module docstring, *on the line*). With
    ``hold_line``, only the face's offset along ``held``'s normal. Held as it was when
    ``fresh`` turns or shifts the face by more than ``max_turn_rad`` or ``max_shift_m``, or
    its centre lies further along it than ``max_slide_m`` and half its length (another
    face); ``fresh``'s id either way (the tracker may give the plate a new track)."""
    n = fresh.normal_xy
    if float(n @ held.normal_xy) < math.cos(max_turn_rad):
        return held
    shift = float((fresh.centre_xy - held.centre_xy) @ (held.normal_xy if hold_line else n))
    if abs(shift) > max_shift_m:
        return held
    if hold_line:
        moved = held.centre_xy + shift * held.normal_xy
        return DockTarget(moved, held.normal_xy.copy(), fresh.obstacle_id, held.length_m)
    slide = float((fresh.centre_xy - held.centre_xy) @ np.array([n[1], -n[0]]))
    if abs(slide) > max(max_slide_m, 0.5 * held.length_m):  # another face along the line
        return held
    if fresh.length_m >= held.length_m - length_tolerance_m and abs(slide) <= max_slide_m:
        return DockTarget(fresh.centre_xy.copy(), n.copy(), fresh.obstacle_id, fresh.length_m)
    return DockTarget(held.centre_xy + shift * n, n.copy(), fresh.obstacle_id, held.length_m)


def search_viewpoint(
    goal_xy: FloatArray,
    radius_m: float,
    searched_xy: FloatArray,
    vehicle_xy: FloatArray,
    obstacles: tuple[FloatArray, FloatArray, FloatArray],
    keep_m: float,
    directions: int = 16,
) -> FloatArray | None:
    """The next place (2,) to look for the docking target from (module docstring,
    *searching*): on the circle of ``radius_m`` about ``goal_xy``, ``keep_m`` clear of the
    ``obstacles`` (capsules: ends ``a``, ``b`` (k, 2) and inflation ``reach`` (k,)), at one
    of ``directions`` bearings about the goal, the one furthest in bearing from every place
    in ``searched_xy`` (m, 2), the nearest to ``vehicle_xy`` among equals; ``None`` when
    every clear bearing lies within half a step of one searched."""
    step = 2.0 * math.pi / directions
    phi = step * np.arange(directions)
    places = goal_xy + radius_m * np.stack([np.cos(phi), np.sin(phi)], axis=1)
    a, b, reach = obstacles
    clear = np.ones(directions, dtype=bool)
    if len(reach):
        gap = point_segment_distance(places[:, None, :], a[None], b[None]) - reach[None]
        clear = gap.min(axis=1) >= keep_m
    apart = np.full(directions, math.pi)
    if len(searched_xy):
        seen = np.arctan2(searched_xy[:, 1] - goal_xy[1], searched_xy[:, 0] - goal_xy[0])
        apart = np.abs(wrap_angle(phi[:, None] - seen[None, :])).min(axis=1)
    ok = clear & (apart >= 0.5 * step)
    if not ok.any():
        return None
    near = np.hypot(*(places - vehicle_xy).T)
    best = np.lexsort((near, -np.round(apart / step)))  # furthest round, then nearest
    pick = int(best[np.flatnonzero(ok[best])[0]])
    return np.asarray(places[pick], dtype=np.float64)


def dock_pose(target: DockTarget, dock_distance_m: float, head_offset_m: float) -> FloatArray:
    """The base_link pose (x, y, yaw) (3,) ``odom`` with the head ``dock_distance_m`` in
    front of the face's centre, facing it."""
    n = target.normal_xy
    base = target.centre_xy + (dock_distance_m + head_offset_m) * n
    return np.array([base[0], base[1], math.atan2(-n[1], -n[0])])


@dataclass(frozen=True)
class LineState:
    """The vehicle against the docking line.

    Attributes
    ----------
    to_go_m
        How far the head still has to go along the line (negative past the stop).
    cross_m
        base_link's distance left of the line.
    head_cross_m
        The head's distance left of the line.
    yaw_error_rad
        Heading less the line's.
    """

    to_go_m: float
    cross_m: float
    head_cross_m: float
    yaw_error_rad: float


def line_state(pose: FloatArray, target_pose: FloatArray, head_offset_m: float) -> LineState:
    """Where ``pose`` (3,) stands against the line ending at ``target_pose`` (3,)."""
    phi = float(target_pose[2])
    u = np.array([math.cos(phi), math.sin(phi)])
    left = np.array([-u[1], u[0]])
    rel = pose[:2] - target_pose[:2]
    e_theta = float(wrap_angle(pose[2] - phi))
    along = float(rel @ u)
    cross = float(rel @ left)
    head_along = along + head_offset_m * (math.cos(e_theta) - 1.0)
    head_cross = cross + head_offset_m * math.sin(e_theta)
    return LineState(-head_along, cross, head_cross, e_theta)


def line_clearance(
    local: LocalState, spec: VehicleSpec, settings: ControllerSettings, dock_distance_m: float
) -> LocalState:
    """``local`` for the last approach: its look-ahead row no further ahead of the bumper
    than ``dock_distance_m`` plus the head's offset, less half the length and
    ``dock_face_gap_m`` (module docstring)."""
    row = local.look_ahead_row
    if row is None:
        return local
    bumper = 0.5 * spec.length_m
    reach = dock_distance_m + spec.head_offset_m - bumper - settings.dock_face_gap_m
    ahead = bumper + max(0.0, reach)
    if ahead >= float(row[0, 0]):
        return local
    return replace(local, look_ahead_row=np.column_stack([np.full(len(row), ahead), row[:, 1]]))


def line_command(
    state: LineState, spec: VehicleSpec, settings: ControllerSettings, tau_s: float
) -> tuple[float, float]:
    """The twist (m/s, rad/s) of the last approach along the line (module docstring)."""
    g = state.to_go_m
    a = 0.5 * spec.max_accel_m_s2
    speed = min(settings.dock_speed_m_s, math.sqrt(2.0 * a * abs(g)), abs(g) / tau_s)
    v = math.copysign(speed, g)
    omega = settings.dock_gain_per_m
    e, s_theta = state.cross_m, math.sin(state.yaw_error_rad)
    kappa = (-1.0 if v >= 0.0 else 1.0) * omega * omega * e - 2.0 * omega * s_theta
    kappa = max(-3.0, min(3.0, kappa))
    w = max(-spec.max_yaw_rate_rad_s, min(spec.max_yaw_rate_rad_s, abs(v) * kappa))
    return v, w
