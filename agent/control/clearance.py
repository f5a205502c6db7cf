"""Known clear space, and how far a motion can go in it: the controller's safety rule.

**The rule.** A command ``(v, w)`` is admissible only if the vehicle, holding it for one
control period plus the latency ``τ`` and then braking along the same arc at its limits,
sweeps nothing but *known clear* space, with ``stop_margin_m`` to spare. In units of the
furthest any point of the outline moves (:mod:`agent.control.geometry`), with
``u = |v| + r·|w|`` and the braking time ``t_b = max(|v|/a, |w|/α)``:

    u·(τ + t_b/2) + margin  <=  d_free(v/u, w/u)                                   (1)

where ``d_free`` is how far the outline moves along the arc before a perimeter point first
enters space not known clear (:meth:`LocalState.free_travel`). :func:`max_scale` solves (1)
for the largest ``λ ≤ 1`` such that ``λ·(v, w)`` is admissible (a quadratic in ``λ``).

**What "known clear" can mean with this sensor.** The sensor sees from 0.4 m to 2.5 m from
the centre of scanning, inside the scanned window (``forward``: ±20° about the heading). The
wedge's apex sits 0.1 m behind the bumper and is only ``0.73·(x + 0.1)`` m wide ``x`` ahead
of it: it covers the vehicle's 0.6 m width only from 0.72 m ahead, and nothing beside or
behind. The agent's profile is stricter still: a bearing counts only as far as it is clear
*from the centre of scanning*, and the first 0.4 m of it are cleared only along beams that
returned from further out; where nothing within range returns light the profile is 0,
however clear the space (measured in the lock-step loop on the random rooms: the forward
window all 0 for seconds at a time), and in open space a no-return is vouched for only in
the right 26° of the window (the left 14.6° could hide a missing part, ``free_space``). So
a cell (5 cm) of the memory about the vehicle (``odom``) is known clear when no inflated
obstacle of the vector covers it (:mod:`agent.control.obstacles`), no possible surface was
seen in it since it was last seen clear (the ``suspect_depth_m`` past a sector's end, when
that end lies between the near limit and ``suspect_max_range_m`` and, where the vector says
(``free_end_hit``), at a surface the agent's scans hit rather than where its knowledge
ends: in open space the sectors end wherever the scans stopped vouching, and such ends
marked the way shut with surfaces that were not there; not a tracked mover's own hits;
forgotten after ``suspect_memory_s``), and

(a) a profile vouched for all of it within ``clear_memory_s`` (its range plus half its
    diagonal within the smallest free range over every sector it spans; the far profile,
    ``free_far_m``, from ``free_far_from_m`` on); or
(b) it was *silent* within ``clear_memory_s``: in the scanned window, between the near
    limit and ``silent_range_m`` (1.0 m), every sector it spans was 0 and returned no light
    nearer than past the cell (the vector's ``scan_dark_m``, where given): the scan crossed
    it and no light came back, which no surface of the worlds could do there (settings). The
    window is the vector's ``scan_window_rad`` where the agent gives it (at any pan, the
    head slewing or not), narrowed to the profile's sectors wholly inside it; where it does
    not (an older agent), the forward window (within
    ``window_half_rad`` of the heading seen from the centre of scanning), and then only
    while the head is taken to scan it (not for 2 s after the profile shows it looked
    elsewhere). Driving forward, this is what shows the corners' way: the window is as
    wide as the vehicle only from 0.85 m out;
(c) the vehicle's own outline (grown by half a cell) covered it within
    ``footprint_memory_s``, or it lies within the circumradius plus ``start_clear_m`` of
    the start pose's centre (the worlds keep that clear: the ring the sensor cannot see
    from the start); or
(d) it is a *pinhole*: unknown, with its eight neighbours known clear (nothing the sensor
    resolves fits in one cell).

The memory's ages (``clear_memory_s``, ``footprint_memory_s``) are seconds of the vehicle's
moving (:mod:`agent.control.memory_clock`): the odometry that placed a cell drifts only
while the wheels turn; and nothing is held once the odometry's heading may have drifted by
``memory_drift_rad`` since it was recorded (:class:`~agent.control.memory_clock.DriftClock`:
1.7 m driven, or 2.5 rad turned, one way). The possible surfaces' ``suspect_memory_s`` is
on the graph clock.

Nothing else is assumed: the space between the outline and the window (beside the vehicle,
and ahead of the bumper until 0.85 m) is known only from other poses, so the controller
looks (turns on the spot where that is admissible) and faces the way ahead before it goes
(:mod:`agent.control.controller`). ``blind_band_m`` (off: 1 mm) would count a band beside
the outline as clear where nothing was seen; the 0.2 m band assumed before is where the
random worlds' collisions were.

Stated limits, besides the agent's own: a mover that enters remembered space unseen is
guarded against only once it is tracked (then it is an inflated, swept obstacle: with the
window ahead, a walker that comes from behind is not; seen in the random worlds as a
walker meeting the vehicle's flank while it backed off); without ``scan_window_rad``,
silence counts as clear on the assumption that the forward window is scanned.

**Unknown space ahead, with a head that pans** (``look_ahead``): a forward motion goes
only as far as keeps a row of points ``look_ahead_m`` (0.3 m) ahead of the bumper out of
unknown cells (``BAND``, or ``UNSEEN``: unknown in the forward window; a possible surface
stays ``BLOCKED``): nearer than that is nearer the centre of scanning than the near limit,
where no look from here can show it. The vehicle then waits for the head to look, rather
than creeping on into space it can never see from where it stops.

**An obstacle the vehicle already overlaps** (its inflation reached the outline: a coasting
track's σ grew, or it was first seen close) would block every motion. Such an *intruder* is
not rasterised; each motion is checked against its core exactly and may go on only while
the outline gets no nearer to the core than now (nor nearer than the full inflation): the
vehicle can back out, never in. A *mover* that intrudes stops the vehicle (it yields).

The check moves the outline's perimeter points (5 cm apart) in steps that move no point
more than one cell, so no blocked cell is passed over; at a cell's corner a miss of less
than a cell is possible, which ``stop_margin_m`` and ``obstacle_margin_m`` absorb.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from agent.arrays import BoolArray, FloatArray, shifted
from agent.compiled import fresh_floats
from agent.control import clearance_kernels as kernels
from agent.control.geometry import (
    motion_poses,
    outline_perimeter,
    point_segment_distance,
    rectangle_segment_distance,
    sweep_points,
    unit_motion,
    wrap_angle,
)
from agent.control.memory_clock import DriftClock, MovingClock
from agent.control.obstacles import Capsules
from agent.control.settings import ControllerSettings
from agent.control.view import EnvironmentView
from agent.kinematics.vehicle import VehicleSpec

__all__ = [
    "BAND",
    "BLOCKED",
    "CLEAR",
    "UNSEEN",
    "ClearanceMap",
    "LocalState",
    "Motions",
    "capsule_cells_reference",
    "compose_cells_reference",
    "forget_movers_hits_reference",
    "free_travel_reference",
    "intruders_ok_reference",
    "max_scale",
    "max_scale_reference",
    "profile_box_reference",
    "rasterise_profile",
    "record_profile",
    "sector_minimum",
]

BLOCKED, CLEAR, BAND, UNSEEN = np.uint8(0), np.uint8(1), np.uint8(2), np.uint8(3)
_SWEPT_MAX_M = 0.5  # a footprint's corners moved further since the last: no sweep recorded


def max_scale(
    v: FloatArray,
    w: FloatArray,
    d_free: FloatArray,
    spec: VehicleSpec,
    tau_s: float,
    margin_m: float,
) -> FloatArray:
    """The largest ``λ`` in [0, 1] such that ``λ·(v, w)`` satisfies (1), (…,).

    Parameters
    ----------
    v, w
        Twists (m/s, rad/s), any shape.
    d_free
        Free travel along each twist's arc (m of the furthest-moving point), same shape.
    tau_s
        The time the command is held before braking can start (period + latency).
    margin_m
        Kept free beyond the stop.

    One-dimensional arrays of one length (every caller's) go to the compiled
    :func:`~agent.control.clearance_kernels.max_scales` (its ten numpy operations cost
    30 µs a call, two calls a command); others to :func:`max_scale_reference`.
    """
    v = np.asarray(v, dtype=np.float64)
    w = np.asarray(w, dtype=np.float64)
    d_free = np.asarray(d_free, dtype=np.float64)
    if v.ndim == 1 and v.shape == w.shape == d_free.shape:
        return kernels.max_scales(
            v, w, d_free, spec.circumradius_m, spec.max_accel_m_s2, spec.max_yaw_accel_rad_s2,
            tau_s, margin_m,
        )  # fmt: skip
    return max_scale_reference(v, w, d_free, spec, tau_s, margin_m)


def max_scale_reference(
    v: FloatArray,
    w: FloatArray,
    d_free: FloatArray,
    spec: VehicleSpec,
    tau_s: float,
    margin_m: float,
) -> FloatArray:
    """:func:`max_scale` in numpy, any shape (its parameters)."""
    av, aw = np.abs(v), np.abs(w)
    u = av + spec.circumradius_m * aw
    beta = np.maximum(av / spec.max_accel_m_s2, aw / spec.max_yaw_accel_rad_s2)
    room = np.maximum(np.asarray(d_free, dtype=np.float64) - margin_m, 0.0)
    B = u * tau_s
    # λ = 2·room / (B + √(B² + 4·A·room)), A = u·β/2: the positive root of A λ² + B λ = room,
    # written so that u = 0 (standing still) gives no division.
    den = B + np.sqrt(B * B + 2.0 * u * beta * room)
    lam = np.where(u > 0.0, 2.0 * room / np.maximum(den, 1e-300), 1.0)
    return np.asarray(np.minimum(lam, 1.0), dtype=np.float64)


def sector_minimum(ranges: FloatArray, lo: FloatArray, hi: FloatArray) -> FloatArray:
    """The smallest of ``ranges`` (b,) over the circular index windows ``[lo, hi]``
    (inclusive, ``lo <= hi``, any integers; at most b long), by a sparse table."""
    b = ranges.size
    length = np.clip(hi - lo + 1, 1, b)
    levels = [ranges]
    while (1 << len(levels)) <= b:
        half = 1 << (len(levels) - 1)
        prev = levels[-1]
        levels.append(np.minimum(prev, np.roll(prev, -half)))
    table = np.stack(levels)
    k = np.floor(np.log2(length)).astype(np.int64)
    first = np.mod(lo, b)
    second = np.mod(lo + length - (1 << k), b)
    return np.asarray(np.minimum(table[k, first], table[k, second]), dtype=np.float64)


@dataclass(frozen=True, eq=False)
class Motions:
    """Motions as arrays, for :func:`free_travel_reference`.

    Attributes
    ----------
    v_unit, w_unit
        (m,) unit motions (:func:`agent.control.geometry.unit_motion`).
    poses_bl
        (m, n, 3) poses at ``n`` steps of ``sweep_step_m`` (step 0 the present),
        ``base_link`` now.
    points_bl
        (m, n, p, 2) the outline's perimeter points at those poses.
    """

    v_unit: FloatArray
    w_unit: FloatArray
    poses_bl: FloatArray
    points_bl: FloatArray

    @classmethod
    def of(
        cls, v: FloatArray, w: FloatArray, spec: VehicleSpec, settings: ControllerSettings
    ) -> Motions:
        """The motions of twists ``(v, w)`` (m,) (their directions only)."""
        v_unit, w_unit = unit_motion(
            np.asarray(v, dtype=np.float64), np.asarray(w, dtype=np.float64), spec.circumradius_m
        )
        poses = motion_poses(v_unit, w_unit, _steps(settings))
        points = sweep_points(poses, outline_perimeter(spec, settings.outline_spacing_m))
        return cls(v_unit, w_unit, poses, points)


def _steps(settings: ControllerSettings) -> FloatArray:
    n = round(settings.sweep_reach_m / settings.sweep_step_m) + 1
    return np.arange(n, dtype=np.float64) * settings.sweep_step_m


@dataclass(frozen=True, eq=False)
class LocalState:
    """Known clear space about the vehicle, ready for :meth:`free_travel`.

    Attributes
    ----------
    origin_xy
        (2,) m, ``odom``: the lower-left corner of cell (0, 0).
    cell_m
        The cells' side.
    state
        (ny, nx) uint8: ``BLOCKED`` (an obstacle or a possible surface), ``CLEAR`` (known
        clear, rules (a) to (d)), ``BAND`` (unknown beside the window: clear if a point
        there is in the blind band) or ``UNSEEN`` (unknown in the window).
    intruders
        Static obstacles whose inflation reaches the outline: checked exactly.
    mover_intrudes
        A mover's swept capsule reaches the outline: the vehicle must stop.
    spec, settings
        The vehicle and the constants the check uses.
    look_ahead_row
        (k, 2) ``base_link`` or ``None``: the row ahead of the bumper that forward motions
        keep out of unknown cells (a head that pans), :func:`look_ahead_row`.
    """

    origin_xy: FloatArray
    cell_m: float
    state: NDArray[np.uint8]
    intruders: Capsules
    mover_intrudes: bool
    spec: VehicleSpec
    settings: ControllerSettings
    look_ahead_row: FloatArray | None = None

    @cached_property
    def _outline(self) -> FloatArray:
        return outline_perimeter(self.spec, self.settings.outline_spacing_m)

    def free_travel(self, pose: FloatArray, v: FloatArray, w: FloatArray) -> FloatArray:
        """How far each twist's arc can go in known clear space.

        Parameters
        ----------
        pose
            (3,) the vehicle now, ``odom``.
        v, w
            (m,) twists (m/s, rad/s): only their directions matter.

        Returns
        -------
        (m,) m of the furthest-moving point: the last step of ``sweep_step_m`` before the
        first step with a perimeter point outside known clear space (0 if the first step
        has one), at most ``sweep_reach_m``.
        """
        v_unit, w_unit = unit_motion(
            np.asarray(v, dtype=np.float64),
            np.asarray(w, dtype=np.float64),
            self.spec.circumradius_m,
        )
        return self.free_travel_unit(pose, v_unit, w_unit)

    def free_travel_unit(
        self, pose: FloatArray, v_unit: FloatArray, w_unit: FloatArray
    ) -> FloatArray:
        """:meth:`free_travel` of the unit motions ``(v_unit, w_unit)`` (m,)
        (:func:`agent.control.geometry.unit_motion`), for a caller that holds them already."""
        spec, st = self.spec, self.settings
        n = self._n_steps
        x, y, yaw = float(pose[0]), float(pose[1]), float(pose[2])
        hx, hy = 0.5 * spec.length_m, 0.5 * spec.width_m
        first = kernels.first_blocked(
            v_unit, w_unit, n, st.sweep_step_m, self._outline, x, y, yaw, self.state,
            float(self.origin_xy[0]), float(self.origin_xy[1]), self.cell_m, hx, hy,
            st.blind_band_m,
        )  # fmt: skip
        if self.look_ahead_row is not None:
            # Forward, no further than keeps unknown space beyond the head's near limit.
            unseen = kernels.first_unseen_ahead(
                v_unit, w_unit, n, st.sweep_step_m, self.look_ahead_row, x, y, yaw,
                self.state, float(self.origin_xy[0]), float(self.origin_xy[1]), self.cell_m,
            )  # fmt: skip
            first = np.minimum(first, np.maximum(unseen, 1))
        if len(self.intruders):
            # Only the steps before the first blocked one can stop a motion sooner.
            first = kernels.first_closer(
                v_unit, w_unit, first, st.sweep_step_m, self.intruders.a, self.intruders.b,
                self._intruders_reach, x, y, yaw, hx, hy,
            )  # fmt: skip
        return np.asarray((np.minimum(first, n) - 1) * st.sweep_step_m, dtype=np.float64)

    @cached_property
    def _n_steps(self) -> int:
        return round(self.settings.sweep_reach_m / self.settings.sweep_step_m) + 1

    @cached_property
    def _intruders_reach(self) -> FloatArray:
        # Once per state: ``Capsules.reach`` adds two arrays at each call, and free_travel
        # runs twice a command.
        return self.intruders.reach


def intruders_ok_reference(local: LocalState, pose: FloatArray, poses_bl: FloatArray) -> BoolArray:
    """(m, n): no step of the motions' poses ``poses_bl`` (m, n, 3) (``base_link`` at
    ``pose``) brings the outline nearer an intruder's core than it is now (or than its full
    reach). The numpy reference of
    :func:`~agent.control.clearance_kernels.first_closer`, which stops at each motion's first
    such step."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    # Intruders' cores in base_link now.
    rel_a = local.intruders.a - pose[:2]
    rel_b = local.intruders.b - pose[:2]
    a_now = np.stack([c * rel_a[:, 0] + s * rel_a[:, 1], -s * rel_a[:, 0] + c * rel_a[:, 1]], 1)
    b_now = np.stack([c * rel_b[:, 0] + s * rel_b[:, 1], -s * rel_b[:, 0] + c * rel_b[:, 1]], 1)
    hx, hy = 0.5 * local.spec.length_m, 0.5 * local.spec.width_m
    d0 = rectangle_segment_distance(a_now, b_now, hx, hy)
    # Each step's frame: p_step = R(θ)·p + t, so p = R(−θ)(p_now − t).
    th = poses_bl[..., 2][..., None]
    ct, st = np.cos(th), np.sin(th)
    tx, ty = poses_bl[..., 0][..., None], poses_bl[..., 1][..., None]

    def to_step(p: FloatArray) -> FloatArray:
        dx, dy = p[:, 0] - tx, p[:, 1] - ty
        return np.stack([ct * dx + st * dy, -st * dx + ct * dy], axis=-1)

    d = rectangle_segment_distance(to_step(a_now), to_step(b_now), hx, hy)
    need = np.minimum(d0, local.intruders.reach) - 1e-3
    return np.asarray((d >= need).all(axis=-1))


def _states_at(
    local: LocalState, pose: FloatArray, points_bl: FloatArray, off_grid: np.uint8
) -> NDArray[np.uint8]:
    """The states of the cells under points (…, 2) (``base_link`` at ``pose``), ``off_grid``
    for those outside the local state."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    px, py = points_bl[..., 0], points_bl[..., 1]
    ny, nx = local.state.shape
    ix = np.floor((pose[0] + c * px - s * py - local.origin_xy[0]) / local.cell_m).astype(np.int64)
    iy = np.floor((pose[1] + s * px + c * py - local.origin_xy[1]) / local.cell_m).astype(np.int64)
    inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
    flat = np.where(inside, iy * nx + ix, 0)
    return np.asarray(np.where(inside, local.state.ravel()[flat], off_grid), dtype=np.uint8)


def free_travel_reference(local: LocalState, pose: FloatArray, motions: Motions) -> FloatArray:
    """:meth:`LocalState.free_travel` in numpy, over whole arrays (what the compiled
    :func:`~agent.control.clearance_kernels.first_blocked` and, with intruders,
    :func:`~agent.control.clearance_kernels.first_closer` and, with the look-ahead row,
    :func:`~agent.control.clearance_kernels.first_unseen_ahead` compute)."""
    points_bl = motions.points_bl
    px, py = points_bl[..., 0], points_bl[..., 1]
    st = _states_at(local, pose, points_bl, BLOCKED)
    hx, hy = 0.5 * local.spec.length_m, 0.5 * local.spec.width_m
    near = np.hypot(np.maximum(np.abs(px) - hx, 0.0), np.maximum(np.abs(py) - hy, 0.0))
    ok = (st == CLEAR) | ((st == BAND) & (near <= local.settings.blind_band_m))
    step_ok = ok.all(axis=-1)
    if len(local.intruders):
        step_ok &= intruders_ok_reference(local, pose, motions.poses_bl)
    step_ok[:, 0] = True
    n = step_ok.shape[1]
    blocked = ~step_ok
    first = np.where(blocked.any(axis=1), blocked.argmax(axis=1), n)
    if local.look_ahead_row is not None:
        row = sweep_points(motions.poses_bl, local.look_ahead_row)  # (m, n, k, 2)
        cells = _states_at(local, pose, row, CLEAR)
        unseen = ((cells == BAND) | (cells == UNSEEN)).any(axis=-1)
        unseen &= (motions.v_unit > 0.0)[:, None]
        at = np.where(unseen.any(axis=1), unseen.argmax(axis=1), n)
        first = np.minimum(first, np.maximum(at, 1))
    return np.asarray((first - 1) * local.settings.sweep_step_m, dtype=np.float64)


def capsule_cells_reference(
    points_xy: FloatArray, capsules: Capsules, half_diag_m: float
) -> BoolArray:
    """Whether points (q, 2) lie within ``reach + half_diag_m`` of any capsule's core: what
    :func:`~agent.control.clearance_kernels.mark_capsules` marks, in numpy."""
    if not len(capsules):
        return np.zeros(len(points_xy), dtype=np.bool_)
    dist = point_segment_distance(points_xy[:, None, :], capsules.a[None], capsules.b[None])
    return np.asarray((dist <= capsules.reach[None] + half_diag_m).any(axis=1))


def look_ahead_row(spec: VehicleSpec, settings: ControllerSettings) -> FloatArray:
    """(k, 2) ``base_link``: points across the vehicle's width (``outline_spacing_m``
    apart, the corners included), ``look_ahead_m`` ahead of its bumper."""
    half = 0.5 * spec.width_m
    k = max(2, math.ceil(spec.width_m / settings.outline_spacing_m) + 1)
    y = np.linspace(-half, half, k)
    return np.stack([np.full(k, 0.5 * spec.length_m + settings.look_ahead_m), y], axis=1)


class ClearanceMap:
    """The memory of space seen clear (and of possible surfaces) about the vehicle, ``odom``.

    A square of ``memory_size_m`` in ``cell_m`` cells, re-centred on the vehicle by whole
    cells when it has moved 1 m from the centre. Each cell holds when a profile last showed
    it clear and when one last showed a possible surface in it.
    """

    def __init__(self, spec: VehicleSpec, settings: ControllerSettings) -> None:
        self.spec = spec
        self.settings = settings
        self.cell_m = settings.cell_m
        self.n = math.ceil(settings.memory_size_m / self.cell_m)
        self.origin_xy: FloatArray | None = None
        self.last_clear = np.full((self.n, self.n), -np.inf)
        self.last_suspect = np.full((self.n, self.n), -np.inf)
        self.last_there = np.full((self.n, self.n), -np.inf)
        self.last_silent = np.full((self.n, self.n), -np.inf)
        self.window_scanned = True
        self.clock = MovingClock()  # the memory's ages: seconds of moving
        self.drift = DriftClock(  # ... and the odometry's heading drift since
            settings.drift_ratio_rad_per_m, settings.drift_track_per_rad,
            settings.drift_slip_rad2_per_m,
        )  # fmt: skip
        half = spec.circumradius_m + settings.sweep_reach_m + 0.25
        self.window_cells = math.ceil(half / self.cell_m)
        self._footprint: tuple[float, FloatArray] | None = None  # the last one recorded
        self._row = look_ahead_row(spec, settings)

    # ------------------------------------------------------------------ the memory grid
    def _since(self, now_s: float) -> tuple[float, float]:
        """What the memory may hold: clear space and the outline's cells recorded after these
        graph times, within ``clear_memory_s`` and ``footprint_memory_s`` of moving and
        ``memory_drift_rad`` of the odometry's heading drift (1σ) of now."""
        st = self.settings
        drift = self.drift.since(st.memory_drift_rad)
        return (
            max(self.clock.since(now_s, st.clear_memory_s), drift),
            max(self.clock.since(now_s, st.footprint_memory_s), drift),
        )

    def _recentre(self, xy: FloatArray) -> None:
        half = 0.5 * self.n * self.cell_m
        if self.origin_xy is None:
            self.origin_xy = np.floor((xy - half) / self.cell_m) * self.cell_m
            return
        # In floats (three calls a vector): the arithmetic of ``|xy − centre| <= 1`` on
        # 2-element arrays, without their 10 µs of numpy calls.
        cx, cy = float(self.origin_xy[0]) + half, float(self.origin_xy[1]) + half
        if abs(float(xy[0]) - cx) <= 1.0 and abs(float(xy[1]) - cy) <= 1.0:
            return
        centre = self.origin_xy + half
        shift = np.round((xy - centre) / self.cell_m).astype(np.int64)
        sx, sy = int(shift[0]), int(shift[1])
        self.last_clear = shifted(self.last_clear, sy, sx)
        self.last_suspect = shifted(self.last_suspect, sy, sx)
        self.last_there = shifted(self.last_there, sy, sx)
        self.last_silent = shifted(self.last_silent, sy, sx)
        self.origin_xy = self.origin_xy + shift * self.cell_m

    def add_profile(
        self, view: EnvironmentView, pose_at_stamp: FloatArray, capsules: Capsules | None = None
    ) -> None:
        """Record the view's profile, seen from ``pose_at_stamp`` (3,) (``odom``); the
        possible surfaces within reach of the ``capsules``' movers are theirs."""
        self._recentre(pose_at_stamp[:2])
        assert self.origin_xy is not None
        # What the scans saw clear, where the agent says, if so set (``record_seen``).
        recorded = view.seen if self.settings.record_seen else view
        record_profile(
            recorded, pose_at_stamp, self.origin_xy, self.cell_m, self.last_clear,
            self.last_suspect, self.spec.head_offset_m, self.settings,
        )  # fmt: skip

        # Silence is evidence only inside a window the head scanned (rule (b)): the one the
        # vector names, else the forward window while the head is taken to scan it.
        window = _silence_window(view, self.settings, self.window_scanned)
        if window is not None:
            x, y, yaw = (float(v) for v in pose_at_stamp)
            h = self.spec.head_offset_m
            centre, half = window
            clear_since, there_since = self._since(view.stamp_s)
            kernels.record_silence(
                self.last_silent, view.stamp_s, float(self.origin_xy[0]),
                float(self.origin_xy[1]), self.cell_m, x + h * math.cos(yaw),
                y + h * math.sin(yaw), yaw + centre, math.tan(half), centre,
                self.settings.near_limit_m, self.settings.silent_range_m,
                _silence_profile(view, self.settings.near_limit_m), view.bearing_step_rad,
                self.last_clear, self.last_suspect, self.last_there,
                clear_since, view.stamp_s - self.settings.suspect_memory_s, there_since,
                x, y, yaw,
                0.5 * self.spec.length_m, 0.5 * self.spec.width_m,
            )  # fmt: skip
        if capsules is not None:
            forget_movers_hits(
                self.last_suspect, self.origin_xy, self.cell_m, capsules, self.settings
            )

    def add_footprint(self, t_s: float, pose: FloatArray, grow_m: float | None = None) -> None:
        """Record that the vehicle's outline (grown by ``grow_m`` on every side; by default
        half a cell) covered its cells at ``t_s``, pose ``pose`` (3,) (``odom``), and the
        cells it swept since the last footprint recorded.

        Half a cell: the cells the outline's edge crosses with their centre outside it would
        otherwise stay unknown, and the perimeter points on the edge lie in them; a vehicle
        that stood still until the rest of its memory aged could then not move at all
        (measured in the random rooms). What the half cell claims beyond the outline,
        2.5 cm, is the discretisation ``stop_margin_m`` already allows for.

        Swept: a vector comes each 0.1 s, and turning on the spot at 1 rad/s the corners
        move 5 cm between two, more than the half cell; the corners' circle was then
        recorded in patches, and a vehicle turning back and forth at its goal found the
        cells its own corners had swept unknown (random run 33 of seed 0, no walkers:
        boxed in until its time ran out). So the outline is also recorded at poses
        between the last one and this (straight-line steps in x, y and heading, each
        moving a corner at most half a cell), at the last one's time; not across a jump
        of more than :data:`_SWEPT_MAX_M` (no sweep to trust) or back in time."""
        if grow_m is None:
            grow_m = 0.5 * self.cell_m
        self._recentre(pose[:2])
        assert self.origin_xy is not None
        poses, stamps = [np.asarray(pose, dtype=np.float64)], [t_s]
        if self._footprint is not None and self._footprint[0] <= t_s:
            t0, last = self._footprint
            turn = float(wrap_angle(pose[2] - last[2]))
            move = float(np.hypot(*(pose[:2] - last[:2]))) + self.spec.circumradius_m * abs(turn)
            n = math.ceil(move / (0.5 * self.cell_m))
            if n > 1 and move <= _SWEPT_MAX_M:
                f = np.arange(1, n) / n
                between = last + f[:, None] * np.array([*(pose[:2] - last[:2]), turn])
                poses = [*between, *poses]
                stamps = [t0] * (n - 1) + stamps
        self._footprint = (t_s, np.asarray(pose, dtype=np.float64).copy())
        for at, stamp in zip(poses, stamps, strict=True):
            kernels.record_outline(
                self.last_there, stamp, float(self.origin_xy[0]), float(self.origin_xy[1]),
                self.cell_m, float(at[0]), float(at[1]), float(at[2]),
                0.5 * self.spec.length_m + grow_m, 0.5 * self.spec.width_m + grow_m,
            )  # fmt: skip

    def add_disc(self, t_s: float, centre_xy: FloatArray, radius_m: float) -> None:
        """Record that nothing static stood within ``radius_m`` of ``centre_xy`` (``odom``)
        at ``t_s``: the cells wholly inside that disc (once, at the start: no hot path)."""
        self._recentre(np.asarray(centre_xy, dtype=np.float64))
        assert self.origin_xy is not None
        half_diag = self.cell_m * math.sqrt(0.5)
        centres = (np.arange(self.n) + 0.5) * self.cell_m
        dx = centres[None, :] + float(self.origin_xy[0] - centre_xy[0])
        dy = centres[:, None] + float(self.origin_xy[1] - centre_xy[1])
        inside = np.hypot(dx, dy) + half_diag <= radius_m
        self.last_there[inside] = np.maximum(self.last_there[inside], t_s)

    # ------------------------------------------------------------------ the local state
    def compose(
        self, now_s: float, pose: FloatArray, capsules: Capsules, look_ahead: bool = False
    ) -> LocalState:
        """Known clear space about ``pose`` (3,) at ``now_s`` (module docstring's rules);
        with ``look_ahead`` (a head that pans), forward motions also keep unknown space out
        of the row ``look_ahead_m`` ahead of the bumper (:func:`look_ahead_row`)."""
        self._recentre(pose[:2])
        assert self.origin_xy is not None
        st = self.settings
        spec = self.spec
        cell = self.cell_m
        # The window's cells in ints and floats (the arithmetic numpy did on 2-element
        # arrays, 20 µs of calls a vector).
        ox, oy = float(self.origin_xy[0]), float(self.origin_xy[1])
        w, n = self.window_cells, self.n
        ix = math.floor((float(pose[0]) - ox) / cell)
        iy = math.floor((float(pose[1]) - oy) / cell)
        lo_x, lo_y = min(max(ix - w, 0), n), min(max(iy - w, 0), n)
        hi_x, hi_y = min(max(ix + w + 1, 0), n), min(max(iy + w + 1, 0), n)
        origin = np.array([ox + lo_x * cell, oy + lo_y * cell])
        clear_since, there_since = self._since(now_s)
        state, candidate = kernels.compose_cells(
            self.last_clear, self.last_suspect, self.last_there, self.last_silent,
            lo_x, lo_y, hi_x - lo_x, hi_y - lo_y, ox, oy, cell,
            float(pose[0]), float(pose[1]), float(pose[2]), spec.head_offset_m,
            0.5 * spec.length_m, 0.5 * spec.width_m, math.tan(st.window_half_rad),
            st.near_limit_m, st.far_limit_m, clear_since, now_s - st.suspect_memory_s,
            there_since,
        )  # fmt: skip
        _fill_pinholes(state)
        half_diag = cell * math.sqrt(0.5)

        # Obstacles: intruders (reaching the outline) apart, the rest rasterised.
        hx, hy = 0.5 * spec.length_m, 0.5 * spec.width_m
        if len(capsules):
            gap = kernels.outline_gaps(
                capsules.a, capsules.b, float(pose[0]), float(pose[1]), float(pose[2]), hx, hy
            )
            intrude = gap < capsules.reach + 2.0 * half_diag
            mover_intrudes = bool((intrude & capsules.moving).any())
            intruders = capsules.select(intrude & ~capsules.moving)
            others = capsules.select(~intrude)
        else:
            mover_intrudes = False
            intruders = others = capsules
        if len(others):
            hit = np.zeros_like(candidate)
            kernels.mark_capsules(
                hit, candidate, float(origin[0]), float(origin[1]), cell,
                others.a, others.b, others.reach,
            )  # fmt: skip
            state[hit] = BLOCKED
        return LocalState(
            origin_xy=origin, cell_m=cell, state=state, intruders=intruders,
            mover_intrudes=mover_intrudes, spec=spec, settings=st,
            look_ahead_row=self._row if look_ahead and st.look_ahead_m > 0.0 else None,
        )  # fmt: skip


def _fill_pinholes(state: NDArray[np.uint8]) -> None:
    """Count as clear each unknown cell (``BAND``: never seen clear, no possible surface
    seen) whose eight neighbours are all clear, in place.

    Such pinholes are the rasterisation's: a cell is clear only when every 1° sector it
    spans vouches for all of it, and the profiles' sectors of different poses leave single
    cells out between cells they cleared (measured in the random rooms: one such cell 5 cm
    ahead of the bumper held the vehicle for 30 s). Nothing the sensor resolves fits in
    one: anything in the cell would reach into a neighbour unless it is under 5 cm across,
    narrower than a 1° sector at 2.5 m (4.4 cm) and than the worlds' thinnest post (10 cm).
    """
    if min(state.shape) < 3:
        return
    clear = state == CLEAR
    inner = clear[:-2, :-2] & clear[:-2, 1:-1] & clear[:-2, 2:]
    inner &= clear[1:-1, :-2] & clear[1:-1, 2:]
    inner &= clear[2:, :-2] & clear[2:, 1:-1] & clear[2:, 2:]
    core = state[1:-1, 1:-1]
    core[inner & (core == BAND)] = CLEAR


def _silence_window(
    view: EnvironmentView, settings: ControllerSettings, forward_scanned: bool
) -> tuple[float, float] | None:
    """Where rule (b) may read silence in ``view``: the window's centre (rad, ``base_link``
    at the stamp) and half-width, or ``None``.

    With ``scan_window_rad`` given, the profile's sectors wholly inside it: each of the
    profile's sectors reaches half a bearing step either side of its bearing, and one
    reaching past the window's edge is 0 also where its outer part was not scanned, so each
    edge moves in to the nearest sector boundary (the forward window, ±20° on the 1° grid
    from −180°, gives ±19.5°: ``window_half_rad``). A window wider than 179° reads nothing
    (the head scans at most 40°). Without it, the forward window (``window_half_rad`` about
    the heading), while ``forward_scanned``."""
    if view.scan_window_rad.size == 2:
        step = view.bearing_step_rad
        if step <= 0.0:
            return None
        low, high = float(view.scan_window_rad[0]), float(view.scan_window_rad[1])
        # Sector boundaries lie at -pi + (k + 1/2)·step.
        low = -math.pi + (math.ceil((low + math.pi) / step - 0.5) + 0.5) * step
        high = -math.pi + (math.floor((high + math.pi) / step - 0.5) + 0.5) * step
        half = 0.5 * (high - low)
        if not 0.0 < half < math.radians(89.5):
            return None
        return 0.5 * (low + high), half
    if forward_scanned:
        return 0.0, settings.window_half_rad
    return None


def _silence_profile(view: EnvironmentView, near_limit_m: float) -> FloatArray:
    """The profile the silence rule reads, per sector: 0 where it is silent as far as the
    silent range, else how far it is (the kernel's cells reaching past a non-zero value are
    not silent).

    A sector known clear from the centre of scanning no further than the near limit (the
    profile's own body edge and the cells just past it) saw nothing beyond it either: it is
    silent (0) unless space beyond the near limit is known clear. Where the vector says how
    far its scan returned no light (``scan_dark_m``), no further than that: a profile's 0
    is also where light came back and left no clear span the agent would keep (a valid
    reading at the window's edge, its sliver aged away at once; a mixed or isolated sample;
    a surface nearer than the near limit), and silence read there went through a wall's end
    (measured: random run 17 of seed 0, ``active``, the vehicle turning in a doorway)."""
    ranges = view.free_range_m
    silence = np.where(ranges < near_limit_m, 0.0, ranges)
    if view.scan_dark_m.size:
        # A sector dark to nowhere (outside the window, light at no known range) is not
        # silent at all: a positive value nearer than any cell.
        dark = np.maximum(view.scan_dark_m, 1e-6)
        silence = np.where(silence == 0.0, dark, np.minimum(silence, dark))
    return np.ascontiguousarray(silence, dtype=np.float64)


def _profile_box(
    view: EnvironmentView,
    pose_at_stamp: FloatArray,
    origin_xy: FloatArray,
    cell_m: float,
    shape: tuple[int, int],
    head_offset_m: float,
    settings: ControllerSettings,
    from_near: bool = False,
) -> tuple[np.ndarray, np.ndarray, FloatArray, FloatArray, FloatArray] | None:
    """The box of cells the profile (``free_far_m`` if ``from_near``, else
    ``free_range_m``) concerns (its lit fan and the suspect depth past it):
    ``(lo, hi, head, ranges, evidence)`` with ``lo``, ``hi`` (x, y) cell indices (``hi``
    exclusive), the centre of scanning (2,), the ranges held to the far limit and the
    evidence (unlit sectors outside the window at +inf); ``None`` if it vouches for
    nothing."""
    b = view.free_range_m.size
    if b == 0:
        return None
    profile = view.free_far_m if from_near else view.free_range_m
    ranges = np.minimum(profile, settings.far_limit_m)
    lit = ranges > 0.0
    if not lit.any():
        return None
    x, y, yaw = (float(v) for v in pose_at_stamp)
    head = np.array([x + head_offset_m * math.cos(yaw), y + head_offset_m * math.sin(yaw)])
    # The box of the centre and the lit sectors' edges' ends (compiled: 2 µs, where the
    # numpy of profile_box_reference takes 27 µs; four times a vector).
    box = kernels.fan_box(
        ranges, fresh_floats(view.free_bearing_rad), yaw, view.bearing_step_rad, float(head[0]),
        float(head[1]), settings.suspect_depth_m,
    )  # fmt: skip
    n_y, n_x = shape
    ox, oy = float(origin_xy[0]), float(origin_xy[1])
    lo_x = min(max(math.floor((box[0] - ox) / cell_m) - 1, 0), n_x)
    lo_y = min(max(math.floor((box[1] - oy) / cell_m) - 1, 0), n_y)
    hi_x = min(max(math.floor((box[2] - ox) / cell_m) + 2, 0), n_x)
    hi_y = min(max(math.floor((box[3] - oy) / cell_m) + 2, 0), n_y)
    if hi_x <= lo_x or hi_y <= lo_y:
        return None
    # Unlit sectors outside the forward window were not scanned: no evidence either way
    # (the cell's part there, within half a cell of the scanned fan's edge, is taken with
    # the rest); unlit sectors within it were scanned and are unknown.
    forward = np.abs(view.free_bearing_rad) <= settings.window_half_rad
    evidence = np.where(lit | forward, ranges, np.inf)
    lo, hi = np.array([lo_x, lo_y]), np.array([hi_x, hi_y])
    return lo, hi, head, ranges, evidence


def profile_box_reference(
    ranges: FloatArray,
    bearings: FloatArray,
    yaw: float,
    step_rad: float,
    head_xy: FloatArray,
    depth_m: float,
) -> tuple[float, float, float, float]:
    """What :func:`~agent.control.clearance_kernels.fan_box` computes, in numpy:
    ``(min_x, min_y, max_x, max_y)`` of the centre ``head_xy`` and the ends of the lit
    sectors' edges ``depth_m`` past their ranges."""
    lit = ranges > 0.0
    reach = ranges[lit] + depth_m
    ang = yaw + bearings[lit]
    ends = np.concatenate(
        [
            np.stack(
                [head_xy[0] + reach * np.cos(ang + d), head_xy[1] + reach * np.sin(ang + d)], 1
            )
            for d in (-0.5 * step_rad, 0.5 * step_rad)
        ]
        + [np.asarray(head_xy, dtype=np.float64)[None]]
    )
    lo, hi = ends.min(axis=0), ends.max(axis=0)
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def record_profile(
    view: EnvironmentView,
    pose_at_stamp: FloatArray,
    origin_xy: FloatArray,
    cell_m: float,
    clear_s: FloatArray,
    suspect_s: FloatArray,
    head_offset_m: float,
    settings: ControllerSettings,
) -> None:
    """Stamp the view's time into ``clear_s`` and ``suspect_s`` (ny, nx), grids in ``odom``
    with lower-left corner ``origin_xy``, where :func:`rasterise_profile` finds the profile
    shows a cell clear, or a possible surface in it: ``free_range_m``'s, then (when the
    view has it) ``free_far_m``'s beyond the near limit (compiled:
    :func:`~agent.control.clearance_kernels.record_profile`)."""
    for from_near in (False, True) if view.free_far_m.size else (False,):
        box = _profile_box(
            view, pose_at_stamp, origin_xy, cell_m, clear_s.shape, head_offset_m, settings,
            from_near,
        )  # fmt: skip
        if box is None:
            continue
        lo, hi, head, ranges, evidence = box
        kernels.record_profile(
            clear_s, suspect_s, view.stamp_s, int(lo[0]), int(hi[0]), int(lo[1]), int(hi[1]),
            float(origin_xy[0]), float(origin_xy[1]), cell_m, float(head[0]), float(head[1]),
            float(pose_at_stamp[2]), ranges, evidence, fresh_floats(view.surface_ends),
            view.bearing_step_rad,
            # The far profile's ends mark no possible surface: a return clears its beam
            # from the centre of scanning, so the first profile's ends are the ones a
            # surface makes.
            math.inf if from_near else settings.near_limit_m, settings.suspect_max_range_m,
            settings.suspect_depth_m, view.free_far_from_m if from_near else 0.0,
        )  # fmt: skip


def forget_movers_hits(
    suspect_s: FloatArray,
    origin_xy: FloatArray,
    cell_m: float,
    capsules: Capsules,
    settings: ControllerSettings,
) -> None:
    """Unmark possible surfaces (``suspect_s`` to −inf) within a tracked mover's swept
    capsule and ``suspect_depth_m``: they are the mover's own hits."""
    if not capsules.moving.any():
        return
    movers = capsules.select(capsules.moving)
    kernels.forget_capsules(
        suspect_s, float(origin_xy[0]), float(origin_xy[1]), cell_m, movers.a, movers.b,
        movers.reach + settings.suspect_depth_m,
    )  # fmt: skip


def forget_movers_hits_reference(
    suspect_s: FloatArray,
    origin_xy: FloatArray,
    cell_m: float,
    capsules: Capsules,
    settings: ControllerSettings,
) -> None:
    """:func:`forget_movers_hits` with grid-sized masks, as it was: the tests' reference."""
    movers = capsules.select(capsules.moving)
    if not len(movers):
        return
    near = np.zeros(suspect_s.shape, dtype=np.bool_)
    kernels.mark_capsules(
        near, np.ones(suspect_s.shape, dtype=np.bool_), float(origin_xy[0]),
        float(origin_xy[1]), cell_m, movers.a, movers.b, movers.reach + settings.suspect_depth_m,
    )  # fmt: skip
    suspect_s[near] = -np.inf


def compose_cells_reference(
    grids: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
    lo: tuple[int, int],
    size: tuple[int, int],
    origin_xy: FloatArray,
    cell_m: float,
    pose: FloatArray,
    spec: VehicleSpec,
    settings: ControllerSettings,
    now_s: float,
) -> tuple[NDArray[np.uint8], BoolArray]:
    """The window's state before obstacles and its open cells, in numpy: what
    :func:`~agent.control.clearance_kernels.compose_cells` computes. ``grids``: when each
    cell was last seen clear, a possible surface, under the vehicle, silent;
    ``lo`` (x, y) the window's first cell in them, ``size`` (n_x, n_y)."""
    rows = slice(lo[1], lo[1] + size[1])
    cols = slice(lo[0], lo[0] + size[0])
    lc, ls, lt, lq = (g[rows, cols] for g in grids)
    xs = origin_xy[0] + (np.arange(lo[0], lo[0] + size[0]) + 0.5) * cell_m
    ys = origin_xy[1] + (np.arange(lo[1], lo[1] + size[1]) + 0.5) * cell_m
    X, Y = np.meshgrid(xs, ys)
    c, s = math.cos(pose[2]), math.sin(pose[2])
    bx = c * (X - pose[0]) + s * (Y - pose[1])  # base_link now
    by = -s * (X - pose[0]) + c * (Y - pose[1])
    fx = bx - spec.head_offset_m
    tan_w = math.tan(settings.window_half_rad)
    r2 = fx * fx + by * by
    in_window = (
        (fx > 0.0) & (np.abs(by) <= tan_w * fx)
        & (r2 >= settings.near_limit_m**2) & (r2 <= settings.far_limit_m**2)
    )  # fmt: skip
    suspect = (ls > np.maximum(np.maximum(lc, lt), lq)) & (ls >= now_s - settings.suspect_memory_s)
    remembered = (
        (lc >= now_s - settings.clear_memory_s)
        | (lq >= now_s - settings.clear_memory_s)
        | (lt >= now_s - settings.footprint_memory_s)
    ) & ~suspect
    known = remembered
    band_ok = ~known & ~suspect & ~in_window
    own = (np.abs(bx) <= 0.5 * spec.length_m) & (np.abs(by) <= 0.5 * spec.width_m)
    unknown = np.where(suspect, BLOCKED, UNSEEN)
    state = np.where(own | known, CLEAR, np.where(band_ok, BAND, unknown)).astype(np.uint8)
    return state, np.asarray((known | band_ok) & ~own)


def rasterise_profile(
    view: EnvironmentView,
    pose_at_stamp: FloatArray,
    origin_xy: FloatArray,
    cell_m: float,
    shape: tuple[int, int],
    head_offset_m: float,
    settings: ControllerSettings,
    from_near: bool = False,
) -> tuple[slice, slice, BoolArray, BoolArray] | None:
    """The cells of a grid (``odom``, lower-left corner ``origin_xy``, ``shape`` (ny, nx))
    that the view's profile shows clear, and those where it shows a possible surface.

    A cell is clear when the sector of its centre is lit and all of it lies within the
    profile: its distance from the centre of scanning plus half its diagonal is within the
    smallest free range over every sector the cell spans (a sector outside the forward
    window that is not lit was not scanned and does not count). It may hold a surface when
    the sector of its centre ends (between the near limit and ``suspect_max_range_m``, and
    at a surface the agent's scans hit where the view says: ``free_end_hit``) within the
    cell or less than ``suspect_depth_m`` before it. The numpy reference of
    :func:`record_profile`.

    Returns
    -------
    ``(rows, cols, clear, suspect)``: the window of the grid concerned and two boolean
    arrays over it; ``None`` when the profile vouches for nothing.
    """
    box = _profile_box(
        view, pose_at_stamp, origin_xy, cell_m, shape, head_offset_m, settings, from_near
    )
    if box is None:
        return None
    lo, hi, head, ranges, evidence = box
    clear_from = view.free_far_from_m if from_near else 0.0
    b = ranges.size
    step = view.bearing_step_rad
    hx, hy, yaw = float(head[0]), float(head[1]), float(pose_at_stamp[2])
    cx = origin_xy[0] + (np.arange(lo[0], hi[0]) + 0.5) * cell_m - hx
    cy = origin_xy[1] + (np.arange(lo[1], hi[1]) + 0.5) * cell_m - hy
    dx, dy = np.meshgrid(cx, cy)  # rows along y, columns along x
    rng = np.hypot(dx, dy)
    half_diag = cell_m * math.sqrt(0.5)
    brg = np.arctan2(dy, dx) - yaw
    spread = np.arcsin(np.minimum(1.0, half_diag / np.maximum(rng, 1e-9)))
    first = np.floor((brg - spread + math.pi) / step + 0.5).astype(np.int64)
    last = np.floor((brg + spread + math.pi) / step + 0.5).astype(np.int64)
    smallest = sector_minimum(evidence, first, last)
    centre = np.mod(np.floor((brg + math.pi) / step + 0.5).astype(np.int64), b)
    end = ranges[centre]
    clear = (
        (end > 0.0) & (rng > half_diag) & (rng - half_diag >= clear_from)
        & (rng + half_diag <= smallest)
    )  # fmt: skip
    suspect = (
        # The far profile's ends mark no possible surface (record_profile, its kernel).
        (not from_near)
        & (view.surface_ends[centre] > 0.0)
        & (end >= settings.near_limit_m)
        & (end < settings.suspect_max_range_m)
        & (rng + half_diag > end)
        & (rng - half_diag <= end + settings.suspect_depth_m)
        & ~clear
    )
    return slice(lo[1], hi[1]), slice(lo[0], hi[0]), clear, suspect
