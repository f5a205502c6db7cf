"""Every message type of the process graph.

Frames (REP-103): ``odom`` (the vehicle's odometry frame), ``map``/``world`` (simulation
truth), ``base_link`` (the vehicle: x forward, y left), ``head`` (the head after pan: x along
the sensor axis). Covariances are row-major ``(..., d, d)`` arrays in the units of the state
they describe.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agent.runtime.messages.schema import (
    Header,
    Message,
    array,
    boolean,
    counters,
    f64,
    i64,
    message,
    text,
)

FloatArray = NDArray[np.float64]
PI = math.pi


@message("heartbeat", 1)
@dataclass(frozen=True, eq=False, kw_only=True)
class Heartbeat(Message):
    """A process is alive: published every heartbeat period on the ``heartbeat`` topic."""

    header: Header
    process: str = text(doc="process name in the launch file")
    pid: int = i64(lo=0)
    state: str = text(choices=("starting", "running", "stopping", "fault"))
    counters: dict[str, int] = counters(doc="received, published, dropped_<kind>, ...")


@message("stop", 1)
@dataclass(frozen=True, eq=False, kw_only=True)
class Stop(Message):
    """Asks every process of the graph (or one, by name) to stop cleanly."""

    header: Header
    reason: str = text(default="")
    process: str = text(default="", doc="empty: every process")


@message("vehicle_state", 1)
@dataclass(frozen=True, eq=False, kw_only=True)
class VehicleState(Message):
    """The agent's input from the vehicle controller (frame ``odom``).

    Pose from odometry, its covariance (3×3 over x, y, yaw), velocity, and where the vehicle
    intends to go: a polyline of waypoints in ``odom``, nearest first (may be empty).
    ``watch_xy`` (w, 2, optional, may be empty): places in ``odom`` the vehicle asks the head
    to look at, nearest first (where walkers it lost may be).
    """

    header: Header
    x_m: float = f64("m")
    y_m: float = f64("m")
    yaw_rad: float = f64("rad", -4 * PI, 4 * PI)
    speed_m_s: float = f64("m/s", -5.0, 5.0)
    yaw_rate_rad_s: float = f64("rad/s", -10.0, 10.0)
    pose_covariance: FloatArray = array("f8", (3, 3), doc="x, y, yaw; m², m·rad, rad²")
    intent_xy: FloatArray = array("f8", ("k", 2), "m", doc="waypoints ahead, odom frame")
    watch_xy: FloatArray = array(
        "f8", ("w", 2), "m", optional=True, doc="places to look at, odom frame; or empty"
    )


@message("wheel_command", 1)
@dataclass(frozen=True, eq=False, kw_only=True)
class WheelCommand(Message):
    """Speed and yaw rate for the differential-drive base (frame ``base_link``)."""

    header: Header
    speed_m_s: float = f64("m/s", -2.0, 2.0)
    yaw_rate_rad_s: float = f64("rad/s", -5.0, 5.0)


@message("world_truth", 2)
@dataclass(frozen=True, eq=False, kw_only=True)
class WorldTruth(Message):
    """Simulation truth (frame ``world``): the vehicle's true pose and velocity, and the
    moving obstacles' true centres and velocities at the stamp (struct of arrays over ``m``
    movers, in the world file's order). For scoring only: no agent stage reads it, except
    the simulated head, which is part of the simulation.

    The vehicle's outline (``agent.kinematics.vehicle.VehicleSpec``) against the true world
    (``agent.sim.footprint``): its clearance now and the least so far (capped at 100 m; -1
    from a writer that did not check), and the first collision, if any: who moved into whom
    (``"vehicle"`` or ``"mover"``; ``""`` none yet) and the obstacle's id (walls, boxes,
    cylinders in file order, then the movers; -1 none). After a collision the vehicle stands
    still for good."""

    header: Header
    x_m: float = f64("m")
    y_m: float = f64("m")
    yaw_rad: float = f64("rad", -4 * PI, 4 * PI)
    speed_m_s: float = f64("m/s", -5.0, 5.0)
    yaw_rate_rad_s: float = f64("rad/s", -10.0, 10.0)
    world_name: str = text(default="")
    mover_xy: FloatArray = array("f8", ("m", 2), "m", doc="true centres")
    mover_velocity_xy: FloatArray = array("f8", ("m", 2), "m/s", -10.0, 10.0)
    mover_radius_m: FloatArray = array("f8", ("m",), "m", 0.0, 10.0)
    clearance_m: float = f64("m", -1.0, 100.0, default=-1.0, doc="outline to nearest obstacle")
    min_clearance_m: float = f64("m", -1.0, 100.0, default=-1.0, doc="least clearance so far")
    collision: str = text(default="", choices=("", "vehicle", "mover"), doc="who moved")
    collision_obstacle: int = i64(lo=-1, default=-1, doc="obstacle id of the collision")


@message("odometry", 1)
@dataclass(frozen=True, eq=False, kw_only=True)
class Odometry(Message):
    """The vehicle base's wheel odometry (frame ``odom``): where it believes it is.

    Integrated from the wheels, so it drifts from the truth; ``pose_covariance`` (3×3 over
    x, y, yaw) is the drift model's estimate of that error, growing with distance and
    turning (``agent.sim.odometry`` documents the model). ``distance_m`` is the path length
    the wheels have measured since the start.
    """

    header: Header
    x_m: float = f64("m")
    y_m: float = f64("m")
    yaw_rad: float = f64("rad", -4 * PI, 4 * PI)
    speed_m_s: float = f64("m/s", -5.0, 5.0)
    yaw_rate_rad_s: float = f64("rad/s", -10.0, 10.0)
    pose_covariance: FloatArray = array("f8", (3, 3), doc="x, y, yaw; m², m·rad, rad²")
    distance_m: float = f64("m", 0.0, None, default=0.0)


@message("head_command", 1)
@dataclass(frozen=True, eq=False, kw_only=True)
class HeadCommand(Message):
    """Point the head and choose the scan window (frame ``base_link``).

    The head accepts pan within ±90° and windows within ±20°; anything else it refuses with a
    :class:`HeadState` whose ``command_accepted`` is false and ``command_message`` says why.
    ``laser`` false parks the mirror and turns the laser off.

    Why (for plots and logs; the head ignores them): ``utility_bits`` and ``cost_s``, the
    winning action's utility and head time when the planner chose it by them (the active
    planner, :mod:`agent.planning.active`); 0 from a policy that weighs nothing.
    """

    header: Header
    pan_rad: float = f64("rad", -PI, PI)
    window_low_rad: float = f64("rad", -PI / 2, PI / 2)
    window_high_rad: float = f64("rad", -PI / 2, PI / 2)
    laser: bool = boolean(default=True)
    utility_bits: float = f64("bit", 0.0, 1e9, default=0.0, doc="the action's utility, or 0")
    cost_s: float = f64("s", 0.0, 60.0, default=0.0, doc="the action's head time, or 0")


@message("head_state", 1)
@dataclass(frozen=True, eq=False, kw_only=True)
class HeadState(Message):
    """What the head is doing, published at every sweep and after every command."""

    header: Header
    pan_rad: float = f64("rad", -PI, PI)
    pan_rate_rad_s: float = f64("rad/s", -20.0, 20.0)
    target_pan_rad: float = f64("rad", -PI, PI)
    window_low_rad: float = f64("rad", -PI / 2, PI / 2)
    window_high_rad: float = f64("rad", -PI / 2, PI / 2)
    laser_on: bool = boolean()
    mode: str = text(choices=("scanning", "slewing", "idle", "fault"))
    command_seq: int = i64(lo=-1, doc="seq of the last command received, -1 if none")
    command_accepted: bool = boolean(default=True)
    command_message: str = text(default="")
    sweeps: int = i64(lo=0)


_SCAN_DOC = "per sample"


@message("raw_scan", 1)
@dataclass(frozen=True, eq=False, kw_only=True)
class RawScan(Message):
    """One sweep as the head measures it (frame ``head``): the input of calibration.

    ``time_s`` is each sample's ADC time; ``mirror_angle_rad`` the mirror's reading then;
    ``pan_rad`` the head's pan; the electrode currents are synchronously detected and
    filtered. ``direction`` is +1/-1 for a sweep towards positive/negative θ, 0 for a stare.
    """

    header: Header
    time_s: FloatArray = array("f8", ("n",), "s", doc=_SCAN_DOC)
    mirror_angle_rad: FloatArray = array("f8", ("n",), "rad", -PI / 2, PI / 2)
    pan_rad: FloatArray = array("f8", ("n",), "rad", -PI, PI)
    current_1_A: FloatArray = array("f8", ("n",), "A", -1e-3, 1e-3)
    current_2_A: FloatArray = array("f8", ("n",), "A", -1e-3, 1e-3)
    direction: int = i64(lo=-1, hi=1)
    sweep_index: int = i64(lo=0, doc="sweeps since the head started")


@message("calibrated_scan", 1)
@dataclass(frozen=True, eq=False, kw_only=True)
class CalibratedScan(Message):
    """Calibrated samples of one sweep (frame ``head``).

    Times and angles are those the samples measure (ADC values less the detection delay).
    ``range_m`` is along the beam from the centre of scanning; NaN where there is no reading;
    ``sigma_m`` its predicted standard deviation (eq. 6.14 through the calibrated gain).
    """

    header: Header
    time_s: FloatArray = array("f8", ("n",), "s")
    scan_angle_rad: FloatArray = array("f8", ("n",), "rad", -PI / 2, PI / 2)
    pan_rad: FloatArray = array("f8", ("n",), "rad", -PI, PI)
    image_position_norm: FloatArray = array("f8", ("n",), "", -1.0, 1.0, allow_nan=True)
    intensity_A: FloatArray = array("f8", ("n",), "A", -1e-3, 1e-3)
    range_m: FloatArray = array("f8", ("n",), "m", 0.0, 100.0, allow_nan=True)
    sigma_m: FloatArray = array("f8", ("n",), "m", 0.0, None, allow_nan=True)
    direction: int = i64(lo=-1, hi=1)
    sweep_index: int = i64(lo=0)
    scan_angle_sigma_rad: float = f64("rad", 0.0, 0.1, default=1e-4)


@message("filtered_scan", 1)
@dataclass(frozen=True, eq=False, kw_only=True)
class FilteredScan(Message):
    """Validated, motion-compensated samples in the vehicle frame (``base_link``).

    The frame is the vehicle's at the scan's reference time, ``header.stamp_ns`` (the last
    sample's time). ``flag`` per sample says why it was kept or dropped (0 valid, 1 no
    reading, 2 low signal, 3 out of range, 4 mixed, 5 isolated); ``segment`` numbers the
    range-continuous runs of valid samples (-1 for dropped). ``points_xy`` are NaN where there
    is no range; ``covariance`` (n, 2, 2) over x, y in m². ``origin_xy`` is the centre of
    scanning each beam left from, in the same frame. ``beam_rad`` (m = n, or empty from an
    older filter) is each beam's direction in the same frame, from the head's pan and the
    mirror's angle at the sample's own time: where a no-return's beam went, also while the
    head slewed.
    """

    header: Header
    points_xy: FloatArray = array("f8", ("n", 2), "m", allow_nan=True)
    covariance: FloatArray = array("f8", ("n", 2, 2), "m²", allow_nan=True)
    origin_xy: FloatArray = array("f8", ("n", 2), "m")
    scan_angle_rad: FloatArray = array("f8", ("n",), "rad", -PI / 2, PI / 2)
    intensity_A: FloatArray = array("f8", ("n",), "A", -1e-3, 1e-3)
    range_m: FloatArray = array("f8", ("n",), "m", 0.0, 100.0, allow_nan=True)
    sigma_m: FloatArray = array("f8", ("n",), "m", 0.0, None, allow_nan=True)
    flag: NDArray[np.uint8] = array("u1", ("n",), lo=0, hi=5)
    segment: NDArray[np.int32] = array("i4", ("n",), lo=-1)
    sweep_index: int = i64(lo=0)
    motion_compensated: bool = boolean(doc="false when no vehicle state had arrived")
    beam_rad: FloatArray = array(
        "f8", ("m",), "rad", -PI, PI, optional=True,
        doc="per sample: the beam's direction in base_link; empty if not given",
    )  # fmt: skip


@message("features", 1)
@dataclass(frozen=True, eq=False, kw_only=True)
class Features(Message):
    """Geometric features of one scan (frame ``base_link`` at the scan's reference time).

    Struct of arrays over ``k`` features. ``kind``: 0 segment, 1 corner, 2 occluding edge,
    3 cylinder. ``params`` (k, 3), NaN beyond each kind's degrees of freedom: segment
    (α rad, ρ m) of the line ``x·cos α + y·sin α = ρ``; corner and edge (x, y) m; cylinder
    (cx, cy, r) m. ``covariance`` (k, 3, 3) over the same parameters, NaN beyond them.
    ``endpoints`` (k, 2, 2): a segment's first and last points, NaN for other kinds.
    ``nearer_side``: for an edge, +1 when the nearer surface lies at higher scan angle, -1
    when at lower; 0 for other kinds. ``reflectivity`` relative to cardboard, NaN if unknown.
    """

    header: Header
    kind: NDArray[np.uint8] = array("u1", ("k",), lo=0, hi=3)
    params: FloatArray = array("f8", ("k", 3), allow_nan=True)
    covariance: FloatArray = array("f8", ("k", 3, 3), allow_nan=True)
    endpoints: FloatArray = array("f8", ("k", 2, 2), "m", allow_nan=True)
    nearer_side: NDArray[np.int32] = array("i4", ("k",), lo=-1, hi=1)
    reflectivity: FloatArray = array("f8", ("k",), lo=0.0, allow_nan=True)
    sweep_index: int = i64(lo=0, default=0)


@message("tracks", 2)
@dataclass(frozen=True, eq=False, kw_only=True)
class Tracks(Message):
    """Feature tracks (frame ``odom``): struct of arrays over ``k`` tracks.

    ``kind`` as in :class:`Features` (0 segment, 1 corner, 2 occluding edge, 3 cylinder);
    ``status``: 0 tentative, 1 confirmed, 2 coasting (confirmed, not seen on the last scan
    that could have seen it, or out of view). ``state`` (k, 4): x, y, vx, vy of the track's
    reference point (segment: midpoint of its extent; corner, edge: the point; cylinder: the
    centre), ``covariance`` (k, 4, 4) over it. ``params`` (k, 3) and ``params_covariance``
    (k, 3, 3) as in :class:`Features` but in ``odom``, NaN beyond each kind's degrees of
    freedom. ``extent`` (k, 4): a segment's end points (x1, y1, x2, y2), a cylinder's radius
    (r, 0, 0, 0), else zeros; ``end_seen`` (k, 2): 1 where that segment end was seen as a
    real end (the surface stops there), 0 where it is only as far as the sensor has looked.
    ``moving_probability``: the chance the feature moves (cylinders; 0 for other kinds).
    ``last_seen_ns``: stamp of the last scan that updated it; ``hits``: updates so far.
    ``information_bits`` (n = k, or empty from an older agent): what its updates have told
    so far, the sum over them of ½·log₂(det P⁻ / det P⁺) of its position (a segment's line
    (α, ρ)), bits.
    """

    header: Header
    track_id: NDArray[np.int64] = array("i8", ("k",), lo=0)
    kind: NDArray[np.uint8] = array("u1", ("k",), lo=0, hi=3)
    status: NDArray[np.uint8] = array("u1", ("k",), lo=0, hi=2)
    state: FloatArray = array("f8", ("k", 4))
    covariance: FloatArray = array("f8", ("k", 4, 4))
    params: FloatArray = array("f8", ("k", 3), allow_nan=True)
    params_covariance: FloatArray = array("f8", ("k", 3, 3), allow_nan=True)
    extent: FloatArray = array("f8", ("k", 4), doc="segment end points or radius, as above")
    end_seen: NDArray[np.uint8] = array("u1", ("k", 2), lo=0, hi=1)
    reflectivity: FloatArray = array("f8", ("k",), lo=0.0, allow_nan=True)
    moving_probability: FloatArray = array("f8", ("k",), "", 0.0, 1.0)
    last_seen_ns: NDArray[np.int64] = array("i8", ("k",), "ns")
    hits: NDArray[np.int64] = array("i8", ("k",), lo=0)
    information_bits: FloatArray = array(
        "f8", ("n",), "bit", 0.0, optional=True,
        doc="per track: information its updates brought so far; empty if not given",
    )  # fmt: skip


@message("environment", 1)
@dataclass(frozen=True, eq=False, kw_only=True)
class EnvironmentVector(Message):
    """The agent's output to the vehicle's path planner (frame ``odom``).

    Obstacles (struct of arrays over ``k``): ``obstacle_id`` is stable while the obstacle is
    tracked; ``kind`` 0 segment, 1 corner, 2 occluding edge, 3 cylinder, 4 docking target;
    ``position_xy`` the reference point (segment midpoint, corner, edge point, cylinder
    centre); ``velocity_xy``; ``covariance`` (k, 4, 4) over x, y, vx, vy; ``extent`` (k, 4):
    segment end points (x1, y1, x2, y2), cylinder (radius, 0, 0, 0), else zeros;
    ``reflectivity`` relative to cardboard.

    Free space: for each bearing in ``free_bearing_rad`` (vehicle frame at the stamp), the
    distance ``free_range_m`` from the centre of scanning known to be clear; 0 where unknown.
    ``free_far_m`` (the same bearings, or empty from an older agent): the distance from the
    centre of scanning such that the space from ``free_far_from_m`` out to it is known clear,
    whether or not the space nearer is. ``free_end_hit`` (the same bearings, or empty from an
    older agent): 1 where ``free_range_m`` ends at a surface the recent scans hit (there may
    be an obstacle not yet tracked), 0 where it ends where the agent's knowledge ends (the
    scans' reach, a gap between beams, space not seen for a while).

    ``scan_window_rad`` (w = 2, or empty): the bearings (low, high), ``base_link`` axes at the
    stamp from the centre of scanning, of the outermost beams of the scan the vector was made
    from, given whenever its beams' directions are known (``filtered_scan/1``'s ``beam_rad``:
    from the head's pan at each sample, slewing or not; from an older filter, only while the
    head's pan held still through the scan); empty when not known (no scan at this stamp,
    an older agent). The schema cannot say "0 or 2,
    low < high": a reader checks that (:class:`agent.control.view.EnvironmentView`).
    ``scan_dark_m`` (the same bearings as the profile, given with ``scan_window_rad``, else
    empty): per sector, how far from the centre of scanning that scan's samples returned no
    light: the range of the nearest that did, the far limit where none did, 0 outside the
    window (and where a sample returned light at no finite range).

    ``seen_range_m``, ``seen_far_m``, ``seen_end_hit`` (the same bearings, or empty from an
    older agent): the three profiles again, of space the recent scans *saw* clear, with no
    allowance for a mover that may have entered it since: for a controller that remembers
    static space and guards against movers by their tracks.

    ``across_sigma_m`` (a = k, or empty from an older agent): per obstacle, for a segment or
    docking target the largest standard deviation of its surface's place across its line over
    its extent (at its end points, from the line's (α, ρ) covariance); 0 for other kinds. A
    segment's ``covariance`` says its midpoint's, whose spread along the line is the
    extent's while its ends are unseen: not how near the surface may come.

    ``seen_age_s`` (g = k, or empty from an older agent): per obstacle, the time from the
    scan that last updated its track to the vector's stamp (0 for one seen in the newest
    scan; a coasting track's grows). ``maintained`` (m = k, or empty): per obstacle, 1
    where the head planner keeps it up to date (it matters for the vehicle's path), 0 where
    it lets it coast; empty when the head policy does not choose (the passive ones, an
    older agent).

    ``sensor_ok`` false means the agent cannot vouch for the vector (head fault, stale data):
    a vehicle must not move on it. ``valid_for_s``: how long it may be used after its stamp.
    """

    header: Header
    obstacle_id: NDArray[np.int64] = array("i8", ("k",), lo=0)
    kind: NDArray[np.uint8] = array("u1", ("k",), lo=0, hi=4)
    position_xy: FloatArray = array("f8", ("k", 2), "m")
    velocity_xy: FloatArray = array("f8", ("k", 2), "m/s")
    covariance: FloatArray = array("f8", ("k", 4, 4))
    extent: FloatArray = array("f8", ("k", 4), "m")
    reflectivity: FloatArray = array("f8", ("k",), lo=0.0, allow_nan=True)
    free_bearing_rad: FloatArray = array("f8", ("b",), "rad", -PI, PI)
    free_range_m: FloatArray = array("f8", ("b",), "m", 0.0, 100.0)
    free_far_m: FloatArray = array(
        "f8", ("n",), "m", 0.0, 100.0, optional=True,
        doc="per bearing: known clear from free_far_from_m out to this; empty if not given",
    )  # fmt: skip
    free_far_from_m: float = f64("m", 0.0, 100.0, default=0.0)
    free_end_hit: NDArray[np.uint8] = array(
        "u1", ("e",), lo=0, hi=1, optional=True,
        doc="per bearing: 1 where free_range_m ends at a surface hit, 0 where knowledge ends",
    )  # fmt: skip
    scan_window_rad: FloatArray = array(
        "f8", ("w",), "rad", -PI, PI, optional=True,
        doc="(low, high) bearings of the scan's outermost beams; empty if not known",
    )  # fmt: skip
    scan_dark_m: FloatArray = array(
        "f8", ("c",), "m", 0.0, 100.0, optional=True,
        doc="per bearing: no light returned nearer than this in the window's scan; or empty",
    )  # fmt: skip
    seen_range_m: FloatArray = array(
        "f8", ("s",), "m", 0.0, 100.0, optional=True,
        doc="per bearing: free_range_m of space seen clear, movers not allowed for; or empty",
    )  # fmt: skip
    seen_far_m: FloatArray = array(
        "f8", ("t",), "m", 0.0, 100.0, optional=True,
        doc="per bearing: free_far_m of space seen clear, movers not allowed for; or empty",
    )  # fmt: skip
    seen_end_hit: NDArray[np.uint8] = array(
        "u1", ("u",), lo=0, hi=1, optional=True,
        doc="per bearing: free_end_hit of seen_range_m; or empty",
    )  # fmt: skip
    across_sigma_m: FloatArray = array(
        "f8", ("a",), "m", 0.0, 100.0, optional=True,
        doc="per obstacle: a segment's largest sigma across its line; 0 other kinds; or empty",
    )  # fmt: skip
    maintained: NDArray[np.uint8] = array(
        "u1", ("m",), lo=0, hi=1, optional=True,
        doc="per obstacle: 1 kept up to date by the head planner, 0 left to coast; or empty",
    )  # fmt: skip
    seen_age_s: FloatArray = array(
        "f8", ("g",), "s", 0.0, 1e6, optional=True,
        doc="per obstacle: time from the scan that last updated it to the stamp; or empty",
    )  # fmt: skip
    sensor_ok: bool = boolean()
    valid_for_s: float = f64("s", 0.0, 60.0, default=0.3)
