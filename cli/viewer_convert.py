"""Bus messages as Foxglove's well-known messages: what ``export --foxglove`` writes and
``view`` serves, so that a recording and a running graph look the same in the Foxglove app.

Channels
--------
=================  ==========================  ==========================  =====================
channel            schema                      from (bus topic)            frame
=================  ==========================  ==========================  =====================
``/tf``            foxglove.FrameTransforms    odometry, head_state,       world → odom →
                                               world_truth, vehicle_state  base_link → head
``/scan``          foxglove.LaserScan          calibrated_scan             base_link
``/scan/points``   foxglove.PointCloud         filtered_scan               base_link
``/features``      foxglove.SceneUpdate        features                    base_link
``/tracks``        foxglove.SceneUpdate        tracks                      odom
``/environment``   foxglove.SceneUpdate        environment                 odom, base_link
``/odometry``      foxglove.Odometry           odometry                    odom
``/vehicle``       foxglove.SceneUpdate        odometry (vehicle_state)    base_link, odom
``/vehicle/path``  foxglove.PosesInFrame       vehicle_state               odom
``/head``          foxglove.SceneUpdate        head_state                  head
``/truth``         foxglove.SceneUpdate        world_truth                 world
``/truth/pose``    foxglove.PoseInFrame        world_truth                 world
``/log``           foxglove.Log                head_state, environment,    -
                                               world_truth
=================  ==========================  ==========================  =====================

Frames (REP-103, everything in the plane z = 0): ``world`` (simulation truth) → ``odom``
(where the odometry believes the vehicle is, drifting from the truth) → ``base_link`` (the
vehicle) → ``head`` (the head after pan, x along the sensor's axis; its origin is the centre of
scanning, ``head_offset_m`` ahead of ``base_link``). ``odom → base_link`` comes from
``odometry``, or from ``vehicle_state`` until an odometry message has arrived (a graph without
the world simulator); ``base_link → head`` from ``head_state``; ``world → odom`` only where the
truth is on the bus: the true pose composed with the inverse of the odometry pose of the same
stamp, so that truth and the agent's view stand side by side, apart by the odometry's error.

Design choices
--------------
* **Scans.** The head may sweep while it pans and the vehicle moves, so a sweep's samples do
  not share one origin and direction. ``/scan`` is each calibrated sweep as a LaserScan in
  ``base_link`` from the centre of scanning, at the bearings (pan + scan angle) of the
  least-squares uniform grid over the sample index: exact for a still head up to the mirror
  reading's jitter (about 2 mrad at the sweep's first sample, 0.4 mrad elsewhere), within
  13 mrad while the head accelerates (the demo run's worst), and refused beyond
  :data:`GRID_TOLERANCE_RAD` (counted). ``/scan/points`` is the filtered, motion-compensated
  scan as a PointCloud: every sample with a position, exactly where filtering placed it, with
  its flag, segment, σ and intensity as fields to colour by.
* **Scene updates** replace the whole scene of their channel: each starts with a deletion of
  every entity older than its stamp, then lists the entities, one per track or obstacle with
  a stable id (``track/12``), so that a track that ends disappears with the next update, and
  a dropped update (a slow WebSocket client) leaves nothing stale behind.
* **Covariance ellipses** are :data:`ELLIPSE_SIGMAS`-σ (as ``run.png`` draws them) of the
  position covariance, from its eigen-decomposition, drawn as closed lines.
* **Times.** Every Foxglove message carries its bus message's ``header.stamp_ns`` (the
  caller's log time where that is 0), and is logged at that time.

The conversions are plain functions of a decoded message; :class:`Converter` holds the little
state between messages (which source places ``base_link``, the pairing of truth and odometry,
the edges that make log lines). The Foxglove SDK is imported only when a conversion runs.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

from agent.kinematics.vehicle import VehicleSpec
from agent.runtime import topics
from agent.runtime.messages import (
    CalibratedScan,
    EnvironmentVector,
    Features,
    FilteredScan,
    HeadState,
    Message,
    Odometry,
    Tracks,
    VehicleState,
    WorldTruth,
)
from agent.sensor.params import SensorParameters

FloatArray = NDArray[np.float64]

# ----------------------------------------------------------------------------- constants
WORLD: Final = "world"
ODOM: Final = "odom"
BASE: Final = "base_link"
HEAD: Final = "head"

TF: Final = "/tf"
SCAN: Final = "/scan"
SCAN_POINTS: Final = "/scan/points"
FEATURES: Final = "/features"
TRACKS: Final = "/tracks"
ENVIRONMENT: Final = "/environment"
ODOMETRY: Final = "/odometry"
VEHICLE: Final = "/vehicle"
VEHICLE_PATH: Final = "/vehicle/path"
HEAD_VIEW: Final = "/head"
TRUTH: Final = "/truth"
TRUTH_POSE: Final = "/truth/pose"
LOG: Final = "/log"

# Each channel's schema: a class of foxglove.messages (and foxglove.channels' "<name>Channel").
CHANNEL_SCHEMAS: Final[dict[str, str]] = {
    TF: "FrameTransforms",
    SCAN: "LaserScan",
    SCAN_POINTS: "PointCloud",
    FEATURES: "SceneUpdate",
    TRACKS: "SceneUpdate",
    ENVIRONMENT: "SceneUpdate",
    ODOMETRY: "Odometry",
    VEHICLE: "SceneUpdate",
    VEHICLE_PATH: "PosesInFrame",
    HEAD_VIEW: "SceneUpdate",
    TRUTH: "SceneUpdate",
    TRUTH_POSE: "PoseInFrame",
    LOG: "Log",
}
# The channels each bus topic may feed; a topic not here is not shown.
TOPIC_CHANNELS: Final[dict[str, tuple[str, ...]]] = {
    topics.CALIBRATED_SCAN: (SCAN,),
    topics.FILTERED_SCAN: (SCAN_POINTS,),
    topics.FEATURES: (FEATURES,),
    topics.TRACKS: (TRACKS,),
    topics.ENVIRONMENT: (ENVIRONMENT, LOG),
    topics.ODOMETRY: (TF, ODOMETRY, VEHICLE),
    topics.VEHICLE_STATE: (TF, VEHICLE, VEHICLE_PATH),
    topics.HEAD_STATE: (TF, HEAD_VIEW, LOG),
    topics.WORLD_TRUTH: (TF, TRUTH, TRUTH_POSE, LOG),
}

ELLIPSE_SIGMAS: Final = 3.0  # covariance ellipses: 3σ (98.9 % of a 2-D Gaussian)
ELLIPSE_POINTS: Final = 32  # vertices of a drawn ellipse
# A sweep whose bearings stray further than this from a uniform grid is not a LaserScan
# (1.1°: 5 cm at 2.5 m); the demo run's worst, the head accelerating, is 0.013 rad.
GRID_TOLERANCE_RAD: Final = 0.02
# Truth and odometry stamps this close are one instant (the world stage stamps both alike).
PAIR_TOLERANCE_NS: Final = 25_000_000
# Foxglove's times are unsigned 32-bit seconds: a stamp from 2106 on has no Foxglove time.
MAX_STAMP_NS: Final = (1 << 32) * 1_000_000_000
MOVING_SPEED_M_S: Final = 0.05  # slower than this, no velocity arrow
LABEL_HEIGHT_M: Final = 0.5  # labels float this far above what they name
FEATURE_HEIGHT_M: Final = 0.3  # cylinders and the vehicle are drawn this tall

KIND_NAMES: Final = ("segment", "corner", "edge", "cylinder", "docking target")
STATUS_NAMES: Final = ("tentative", "confirmed", "coasting")
FLAG_NAMES: Final = ("valid", "no reading", "low signal", "out of range", "mixed", "isolated")

Rgba = tuple[float, float, float, float]
COLOURS: Final[dict[str, Rgba]] = {
    "tentative": (0.6, 0.6, 0.6, 0.8),  # tracks by status
    "confirmed": (0.2, 0.6, 1.0, 1.0),
    "coasting": (1.0, 0.6, 0.1, 1.0),
    "moving": (0.9, 0.2, 0.8, 1.0),  # a cylinder more likely moving than not
    "maintained": (0.1, 0.8, 0.3, 1.0),  # environment obstacles: kept up to date by the head
    "left to coast": (1.0, 0.6, 0.1, 1.0),  # ... or not
    "obstacle": (0.9, 0.9, 0.9, 1.0),  # ... when the head policy does not choose
    "docking target": (1.0, 0.85, 0.0, 1.0),
    "free space": (0.1, 0.8, 0.3, 0.15),
    "scan window": (1.0, 1.0, 1.0, 0.6),
    "segment": (1.0, 1.0, 1.0, 1.0),  # features by kind
    "corner": (1.0, 0.9, 0.2, 1.0),
    "edge": (1.0, 0.5, 0.2, 1.0),
    "cylinder": (0.2, 0.9, 0.9, 1.0),
    "vehicle": (0.3, 0.5, 0.9, 0.35),
    "odometry ellipse": (1.0, 1.0, 0.2, 0.9),
    "scanning": (0.1, 0.8, 0.3, 0.8),  # the head by mode
    "slewing": (1.0, 0.85, 0.0, 0.8),
    "idle": (0.6, 0.6, 0.6, 0.8),
    "fault": (1.0, 0.1, 0.1, 1.0),
    "ok": (0.1, 0.8, 0.3, 1.0),
    "not ok": (1.0, 0.1, 0.1, 1.0),
    "truth vehicle": (1.0, 1.0, 1.0, 0.25),
    "truth mover": (0.9, 0.1, 0.1, 0.6),
    "label": (1.0, 1.0, 1.0, 1.0),
}

Output = tuple[str, Any]  # (channel, a foxglove.messages object)

__all__ = [
    "CHANNEL_SCHEMAS", "ELLIPSE_SIGMAS", "TOPIC_CHANNELS", "Converter", "bearing_grid",
    "ellipse_axes", "ellipse_points", "laser_scan", "scan_points", "tracks_update",
    "world_to_odom", "yaw_quaternion",
]  # fmt: skip


# -------------------------------------------------------------------------------- maths
def yaw_quaternion(yaw_rad: float) -> tuple[float, float, float, float]:
    """The quaternion (x, y, z, w) of a rotation by ``yaw_rad`` about z."""
    return (0.0, 0.0, math.sin(0.5 * yaw_rad), math.cos(0.5 * yaw_rad))


def world_to_odom(
    true_pose: tuple[float, float, float], odom_pose: tuple[float, float, float]
) -> tuple[float, float, float]:
    """The pose (x m, y m, yaw rad) of ``odom`` in ``world``, from the vehicle's pose in each
    at one instant: ``T_world_odom = T_world_base · T_odom_base⁻¹``."""
    xt, yt, yaw_t = true_pose
    xo, yo, yaw_o = odom_pose
    yaw = yaw_t - yaw_o
    c, s = math.cos(yaw), math.sin(yaw)
    return (xt - (c * xo - s * yo), yt - (s * xo + c * yo), yaw)


def ellipse_axes(
    cov: FloatArray, sigmas: float = ELLIPSE_SIGMAS
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The ``sigmas``-σ ellipses of 2-D covariances.

    Parameters
    ----------
    cov
        (..., 2, 2) covariances, m² (symmetrised; negative eigenvalues, rounding, taken as 0).

    Returns
    -------
    semi_major, semi_minor
        (...) the semi-axes, m: ``sigmas`` times the square roots of the eigenvalues.
    angle
        (...) the major axis's direction, rad in (-π/2, π/2].
    """
    sym = 0.5 * (cov + np.swapaxes(cov, -1, -2))
    values, vectors = np.linalg.eigh(sym)  # ascending eigenvalues, vectors in columns
    values = np.clip(values, 0.0, None)
    semi_major = sigmas * np.sqrt(values[..., 1])
    semi_minor = sigmas * np.sqrt(values[..., 0])
    angle = np.arctan2(vectors[..., 1, 1], vectors[..., 0, 1])
    angle = np.where(angle > 0.5 * math.pi, angle - math.pi, angle)
    angle = np.where(angle <= -0.5 * math.pi, angle + math.pi, angle)
    return semi_major, semi_minor, angle


def ellipse_points(
    centre: FloatArray,
    cov: FloatArray,
    sigmas: float = ELLIPSE_SIGMAS,
    n_points: int = ELLIPSE_POINTS,
) -> FloatArray:
    """Vertices (..., n_points, 2), m, of the ``sigmas``-σ ellipses of covariances ``cov``
    (..., 2, 2) about ``centre`` (..., 2), counter-clockwise from the major axis's end."""
    semi_major, semi_minor, angle = ellipse_axes(cov, sigmas)
    t = np.linspace(0.0, 2.0 * math.pi, n_points, endpoint=False)
    u = semi_major[..., None] * np.cos(t)  # along the major axis
    v = semi_minor[..., None] * np.sin(t)
    c, s = np.cos(angle)[..., None], np.sin(angle)[..., None]
    return np.stack([c * u - s * v, s * u + c * v], axis=-1) + centre[..., None, :]


def bearing_grid(bearings_rad: FloatArray) -> tuple[float, float, float]:
    """The uniform grid nearest (least squares over the sample index) to a sweep's bearings:
    its first and last bearings, rad, and the largest distance of a bearing from it, rad.
    Non-finite bearings make the distance infinite."""
    n = bearings_rad.size
    if n == 0:
        return 0.0, 0.0, math.inf
    if n == 1:
        b = float(bearings_rad[0])
        return b, b, 0.0 if math.isfinite(b) else math.inf
    i = np.arange(n, dtype=np.float64)
    i_mean = 0.5 * (n - 1)
    b_mean = float(bearings_rad.mean())
    slope = float(((i - i_mean) * (bearings_rad - b_mean)).sum() / ((i - i_mean) ** 2).sum())
    fit = b_mean + slope * (i - i_mean)
    deviation = float(np.abs(bearings_rad - fit).max())
    if not math.isfinite(deviation):
        deviation = math.inf
    return float(fit[0]), float(fit[-1]), deviation


def _rotate(xy: FloatArray, yaw_rad: float) -> FloatArray:
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.stack([c * xy[..., 0] - s * xy[..., 1], s * xy[..., 0] + c * xy[..., 1]], axis=-1)


def _arc(radius_m: float, low_rad: float, high_rad: float, n: int = 16) -> FloatArray:
    t = np.linspace(low_rad, high_rad, n)
    return radius_m * np.stack([np.cos(t), np.sin(t)], axis=-1)


# ---------------------------------------------------------------------- Foxglove pieces
def _fm() -> Any:
    """``foxglove.messages``, imported on first use (an optional dependency)."""
    import foxglove.messages

    return foxglove.messages


def _time(stamp_ns: int) -> Any:
    return _fm().Timestamp(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000)


def _pose(x: float = 0.0, y: float = 0.0, yaw_rad: float = 0.0, z: float = 0.0) -> Any:
    fm = _fm()
    qx, qy, qz, qw = yaw_quaternion(yaw_rad)
    return fm.Pose(
        position=fm.Vector3(x=x, y=y, z=z), orientation=fm.Quaternion(x=qx, y=qy, z=qz, w=qw)
    )


def _colour(name: str) -> Any:
    r, g, b, a = COLOURS[name]
    return _fm().Color(r=r, g=g, b=b, a=a)


def _points(xy: FloatArray, z: float = 0.0) -> list[Any]:
    point3 = _fm().Point3
    return [point3(x=x, y=y, z=z) for x, y in np.asarray(xy, dtype=np.float64).tolist()]


def _line(xy: FloatArray, colour: str, thickness_m: float = 0.02, closed: bool = False) -> Any:
    fm = _fm()
    kind = fm.LinePrimitiveLineType.LineLoop if closed else fm.LinePrimitiveLineType.LineStrip
    return fm.LinePrimitive(
        type=kind, pose=_pose(), thickness=thickness_m, points=_points(xy), color=_colour(colour)
    )


def _segments(xy_pairs: FloatArray, colour: str, thickness_m: float = 0.02) -> Any:
    """One LinePrimitive drawing every (2, 2) pair of ``xy_pairs`` (k, 2, 2) as a segment."""
    fm = _fm()
    return fm.LinePrimitive(
        type=fm.LinePrimitiveLineType.LineList, pose=_pose(), thickness=thickness_m,
        points=_points(np.asarray(xy_pairs).reshape(-1, 2)), color=_colour(colour),
    )  # fmt: skip


def _text(x: float, y: float, text: str, colour: str = "label") -> Any:
    return _fm().TextPrimitive(
        pose=_pose(x, y, z=LABEL_HEIGHT_M), billboard=True, font_size=14.0,
        scale_invariant=True, color=_colour(colour), text=text,
    )  # fmt: skip


def _sphere(x: float, y: float, size_m: float, colour: str) -> Any:
    fm = _fm()
    return fm.SpherePrimitive(
        pose=_pose(x, y), size=fm.Vector3(x=size_m, y=size_m, z=size_m), color=_colour(colour)
    )


def _cylinder(x: float, y: float, radius_m: float, colour: str) -> Any:
    fm = _fm()
    d = 2.0 * radius_m
    return fm.CylinderPrimitive(
        pose=_pose(x, y, z=0.5 * FEATURE_HEIGHT_M), size=fm.Vector3(x=d, y=d, z=FEATURE_HEIGHT_M),
        bottom_scale=1.0, top_scale=1.0, color=_colour(colour),
    )  # fmt: skip


def _arrow(x: float, y: float, vx: float, vy: float, colour: str) -> Any | None:
    """Where the point will be in one second, as an arrow; ``None`` when it hardly moves."""
    speed = math.hypot(vx, vy)
    if not math.isfinite(speed) or speed < MOVING_SPEED_M_S:
        return None
    return _fm().ArrowPrimitive(
        pose=_pose(x, y, math.atan2(vy, vx)), shaft_length=0.8 * speed, shaft_diameter=0.02,
        head_length=0.2 * speed, head_diameter=0.06, color=_colour(colour),
    )  # fmt: skip


def _metadata(**values: object) -> list[Any]:
    pair = _fm().KeyValuePair
    return [pair(key=k, value=str(v)) for k, v in values.items()]


def _entity(stamp_ns: int, frame_id: str, entity_id: str, **parts: Any) -> Any:
    return _fm().SceneEntity(timestamp=_time(stamp_ns), frame_id=frame_id, id=entity_id, **parts)


def _scene(stamp_ns: int, entities: list[Any]) -> Any:
    """A scene update that replaces every entity of its channel older than ``stamp_ns``."""
    fm = _fm()
    clear = fm.SceneEntityDeletion(timestamp=_time(stamp_ns), type=fm.SceneEntityDeletionType.All)
    return fm.SceneUpdate(deletions=[clear], entities=entities)


def _transform(stamp_ns: int, parent: str, child: str, x: float, y: float, yaw: float) -> Any:
    fm = _fm()
    qx, qy, qz, qw = yaw_quaternion(yaw)
    return fm.FrameTransform(
        timestamp=_time(stamp_ns), parent_frame_id=parent, child_frame_id=child,
        translation=fm.Vector3(x=x, y=y, z=0.0), rotation=fm.Quaternion(x=qx, y=qy, z=qz, w=qw),
    )  # fmt: skip


def _pose_covariance_6(cov3: FloatArray) -> list[float]:
    """A (3, 3) covariance over (x, y, yaw) as Foxglove's row-major 6×6 over (x, y, z, roll,
    pitch, yaw), zero for the unobserved axes."""
    cov6 = np.zeros((6, 6))
    axes = np.array([0, 1, 5])
    cov6[np.ix_(axes, axes)] = cov3
    return list(cov6.ravel().tolist())


# -------------------------------------------------------------------------- conversions
def laser_scan(msg: CalibratedScan, head_offset_m: float) -> Any | None:
    """A calibrated sweep as a LaserScan in ``base_link`` at its stamp, from the centre of
    scanning ``head_offset_m`` ahead, at the bearings of the uniform grid nearest the samples'
    pan + scan angle (module docstring); ``None`` when they stray from it by more than
    :data:`GRID_TOLERANCE_RAD` (or there are no samples). Ranges in m, NaN where there is no
    reading; intensities in nA."""
    start, end, deviation = bearing_grid(msg.pan_rad + msg.scan_angle_rad)
    if not deviation <= GRID_TOLERANCE_RAD:
        return None
    return _fm().LaserScan(
        timestamp=_time(msg.header.stamp_ns), frame_id=BASE, pose=_pose(head_offset_m, 0.0),
        start_angle=start, end_angle=end, ranges=msg.range_m.tolist(),
        intensities=(msg.intensity_A * 1e9).tolist(),
    )  # fmt: skip


# The PointCloud's packed layout: float32 x, y, z, intensity (nA), σ (mm); int32 segment;
# uint8 flag (FilteredScan's codes); 3 bytes of padding.
_POINT_DTYPE: Final = np.dtype(
    {
        "names": ["x", "y", "z", "intensity_nA", "sigma_mm", "segment", "flag"],
        "formats": ["<f4", "<f4", "<f4", "<f4", "<f4", "<i4", "u1"],
        "offsets": [0, 4, 8, 12, 16, 20, 24],
        "itemsize": 28,
    }
)


def scan_points(msg: FilteredScan) -> Any:
    """A filtered scan as a PointCloud in ``base_link`` at its stamp: every sample that has a
    position (dropped ones too, with their flag), with fields ``intensity_nA``, ``sigma_mm``,
    ``segment`` (-1 dropped) and ``flag`` (0 valid, 1 no reading, 2 low signal, 3 out of
    range, 4 mixed, 5 isolated)."""
    fm = _fm()
    keep = np.isfinite(msg.points_xy).all(axis=1)
    packed = np.zeros(int(keep.sum()), dtype=_POINT_DTYPE)
    packed["x"] = msg.points_xy[keep, 0]
    packed["y"] = msg.points_xy[keep, 1]
    packed["intensity_nA"] = msg.intensity_A[keep] * 1e9
    packed["sigma_mm"] = msg.sigma_m[keep] * 1e3
    packed["segment"] = msg.segment[keep]
    packed["flag"] = msg.flag[keep]
    numeric = fm.PackedElementFieldNumericType
    types = {"<f4": numeric.Float32, "<i4": numeric.Int32, "|u1": numeric.Uint8}
    fields = [
        fm.PackedElementField(name=name, offset=offset, type=types[dtype.str])
        for name, (dtype, offset) in _POINT_DTYPE.fields.items()
    ]
    return fm.PointCloud(
        timestamp=_time(msg.header.stamp_ns), frame_id=msg.header.frame_id or BASE,
        pose=_pose(), point_stride=_POINT_DTYPE.itemsize, fields=fields, data=packed.tobytes(),
    )  # fmt: skip


def features_update(msg: Features) -> Any:
    """One scan's features in ``base_link`` at the scan's stamp, as one entity: segments as
    lines between their end points, corners and edges as dots with their position ellipses,
    cylinders as cylinders with their centre's ellipse; colours by kind."""
    stamp = msg.header.stamp_ns
    kind = msg.kind
    lines = []
    segments = msg.endpoints[kind == 0]
    segments = segments[np.isfinite(segments).all(axis=(1, 2))]
    if len(segments):
        lines.append(_segments(segments, "segment", 0.03))
    spheres, cylinders = [], []
    pointlike = (kind == 1) | (kind == 2) | (kind == 3)
    centres = msg.params[:, :2]
    ok = (
        pointlike
        & np.isfinite(centres).all(axis=1)
        & np.isfinite(msg.covariance[:, :2, :2]).all(axis=(1, 2))
    )
    cov = np.where(ok[:, None, None], msg.covariance[:, :2, :2], 0.0)  # NaN: not drawn
    rings = ellipse_points(np.where(ok[:, None], centres, 0.0), cov)
    for i in np.flatnonzero(ok).tolist():
        name = KIND_NAMES[int(kind[i])]
        x, y = float(centres[i, 0]), float(centres[i, 1])
        if kind[i] == 3:
            cylinders.append(_cylinder(x, y, float(msg.params[i, 2]), name))
        else:
            spheres.append(_sphere(x, y, 0.06, name))
        lines.append(_line(rings[i], name, 0.01, closed=True))
    entity = _entity(
        stamp, msg.header.frame_id or BASE, "features", lines=lines, spheres=spheres,
        cylinders=cylinders, metadata=_metadata(features=len(kind), sweep=msg.sweep_index),
    )  # fmt: skip
    return _scene(stamp, [entity])


def _obstacle_parts(
    kind: int, x: float, y: float, extent: FloatArray, colour: str
) -> dict[str, list[Any]]:
    """How an obstacle of ``kind`` at (x, y) with ``extent`` (4,) is drawn."""
    if kind in (0, 4) and np.isfinite(extent).all() and np.any(extent != 0.0):
        return {"lines": [_line(extent.reshape(2, 2), colour, 0.04)]}
    if kind == 3 and math.isfinite(float(extent[0])) and extent[0] > 0.0:
        return {"cylinders": [_cylinder(x, y, float(extent[0]), colour)]}
    return {"spheres": [_sphere(x, y, 0.08, colour)]}


def tracks_update(msg: Tracks) -> Any:
    """Every track (``odom``) as an entity ``track/<id>``: its feature (segment as a line
    between its end points, with a dot at each end seen as a real end; corner and edge as a
    dot; cylinder as a cylinder), its position's ellipse, a velocity arrow when it moves, and
    a label ``<id> <kind> <status>``; colours by status (tentative grey, confirmed blue,
    coasting orange; a cylinder more likely moving than not magenta). The selection panel
    shows hits, last seen, reflectivity, moving probability and information."""
    stamp = msg.header.stamp_ns
    frame = msg.header.frame_id or ODOM
    rings = ellipse_points(msg.state[:, :2], msg.covariance[:, :2, :2])
    info = msg.information_bits if msg.information_bits.size == msg.track_id.size else None
    entities = []
    for i in range(msg.track_id.size):
        kind, status = int(msg.kind[i]), int(msg.status[i])
        x, y, vx, vy = (float(v) for v in msg.state[i])
        moving = kind == 3 and msg.moving_probability[i] >= 0.5
        colour = "moving" if moving else STATUS_NAMES[status]
        parts = _obstacle_parts(kind, x, y, msg.extent[i], colour)
        if kind == 0:
            ends = msg.extent[i].reshape(2, 2)[msg.end_seen[i] == 1]
            parts["spheres"] = [_sphere(float(e[0]), float(e[1]), 0.06, colour) for e in ends]
        parts.setdefault("lines", []).append(_line(rings[i], colour, 0.01, closed=True))
        arrow = _arrow(x, y, vx, vy, colour)
        if arrow is not None:
            parts["arrows"] = [arrow]
        track_id = int(msg.track_id[i])
        label = f"{track_id} {KIND_NAMES[kind]} {STATUS_NAMES[status]}"
        if kind == 3:
            label += f" (moving {msg.moving_probability[i]:.0%})"
        parts["texts"] = [_text(x, y, label, colour)]
        details = {
            "kind": KIND_NAMES[kind], "status": STATUS_NAMES[status], "hits": int(msg.hits[i]),
            "last_seen_s": f"{msg.last_seen_ns[i] * 1e-9:.3f}",
            "moving_probability": f"{msg.moving_probability[i]:.3f}",
            "reflectivity": f"{msg.reflectivity[i]:.2f}", "speed_m_s": f"{math.hypot(vx, vy):.3f}",
        }  # fmt: skip
        if info is not None:
            details["information_bits"] = f"{info[i]:.2f}"
        entities.append(
            _entity(stamp, frame, f"track/{track_id}", metadata=_metadata(**details), **parts)
        )
    return _scene(stamp, entities)


def environment_update(msg: EnvironmentVector, head_offset_m: float, far_m: float) -> Any:
    """The environment vector: every obstacle (``odom``) as an entity ``obstacle/<id>``
    (drawn as tracks are, with its position ellipse, velocity arrow and a label
    ``<id> <kind> maintained|left to coast``; green where the head planner keeps it up to
    date, orange where it lets it coast, grey when the policy does not choose, gold for a
    docking target); the free space (``base_link`` at the stamp) as a translucent green fan
    from the centre of scanning, the scan window's outer beams as white rays ``far_m`` long;
    and ``status``, a label over the vehicle: sensor ok (green) or NOT OK (red: a vehicle must
    not move)."""
    stamp = msg.header.stamp_ns
    frame = msg.header.frame_id or ODOM
    k = msg.obstacle_id.size
    maintained = msg.maintained if msg.maintained.size == k else None
    rings = ellipse_points(msg.position_xy, msg.covariance[:, :2, :2])
    entities = []
    for i in range(k):
        kind = int(msg.kind[i])
        x, y = (float(v) for v in msg.position_xy[i])
        if kind == 4:
            colour = "docking target"
        elif maintained is None:
            colour = "obstacle"
        else:
            colour = "maintained" if maintained[i] else "left to coast"
        parts = _obstacle_parts(kind, x, y, msg.extent[i], colour)
        parts.setdefault("lines", []).append(_line(rings[i], colour, 0.01, closed=True))
        arrow = _arrow(x, y, float(msg.velocity_xy[i, 0]), float(msg.velocity_xy[i, 1]), colour)
        if arrow is not None:
            parts["arrows"] = [arrow]
        obstacle_id = int(msg.obstacle_id[i])
        label = f"{obstacle_id} {KIND_NAMES[kind]}"
        if maintained is not None:
            label += " maintained" if maintained[i] else " left to coast"
        parts["texts"] = [_text(x, y, label, colour)]
        meta = _metadata(kind=KIND_NAMES[kind], reflectivity=f"{msg.reflectivity[i]:.2f}")
        entities.append(_entity(stamp, frame, f"obstacle/{obstacle_id}", metadata=meta, **parts))

    origin = np.array([head_offset_m, 0.0])
    order = np.argsort(msg.free_bearing_rad)
    bearing, reach = msg.free_bearing_rad[order], msg.free_range_m[order]
    ends = origin + reach[:, None] * np.stack([np.cos(bearing), np.sin(bearing)], axis=-1)
    known = (reach[:-1] > 0.0) & (reach[1:] > 0.0)
    fan = np.stack([np.broadcast_to(origin, ends[:-1].shape), ends[:-1], ends[1:]], axis=1)
    free: dict[str, list[Any]] = {}
    if known.any():
        triangles = _points(fan[known].reshape(-1, 2))
        free["triangles"] = [
            _fm().TriangleListPrimitive(pose=_pose(), points=triangles, color=_colour("free space"))
        ]
    if msg.scan_window_rad.size == 2:
        beams = np.stack([np.cos(msg.scan_window_rad), np.sin(msg.scan_window_rad)], axis=-1)
        far = origin + far_m * beams
        rays = np.stack([np.broadcast_to(origin, far.shape), far], axis=1)
        free["lines"] = [_segments(rays, "scan window", 0.01)]
    entities.append(_entity(stamp, BASE, "free_space", **free))
    state = "ok" if msg.sensor_ok else "not ok"
    words = f"sensor ok, valid {msg.valid_for_s:.2f} s" if msg.sensor_ok else "SENSOR NOT OK"
    entities.append(_entity(stamp, BASE, "status", texts=[_text(0.0, 0.0, words, state)]))
    return _scene(stamp, entities)


def odometry_message(msg: Odometry) -> Any:
    """The wheel odometry as Foxglove's Odometry: pose in ``odom``, velocities in
    ``base_link``, the (x, y, yaw) covariance in the 6×6 layout."""
    fm = _fm()
    return fm.Odometry(
        timestamp=_time(msg.header.stamp_ns), frame_id=msg.header.frame_id or ODOM,
        body_frame_id=BASE, pose=_pose(msg.x_m, msg.y_m, msg.yaw_rad),
        linear_velocity=fm.Vector3(x=msg.speed_m_s, y=0.0, z=0.0),
        angular_velocity=fm.Vector3(x=0.0, y=0.0, z=msg.yaw_rate_rad_s),
        pose_covariance=_pose_covariance_6(msg.pose_covariance),
        metadata=_metadata(distance_m=f"{msg.distance_m:.3f}"),
    )  # fmt: skip


def base_transform(msg: Odometry | VehicleState) -> Any:
    """``odom → base_link`` at the message's stamp."""
    return _transform(
        msg.header.stamp_ns, msg.header.frame_id or ODOM, BASE, msg.x_m, msg.y_m, msg.yaw_rad
    )


def head_transform(msg: HeadState, head_offset_m: float) -> Any:
    """``base_link → head``: the centre of scanning, turned by the pan."""
    return _transform(
        msg.header.stamp_ns, msg.header.frame_id or BASE, HEAD, head_offset_m, 0.0, msg.pan_rad
    )


def vehicle_update(msg: Odometry | VehicleState, vehicle: VehicleSpec) -> Any:
    """The vehicle as the agent believes it: its outline (``vehicle``, following
    ``base_link``) and the odometry's position ellipse (``pose_ellipse``, ``odom``)."""
    fm = _fm()
    stamp = msg.header.stamp_ns
    body = fm.CubePrimitive(
        pose=_pose(z=0.5 * FEATURE_HEIGHT_M),
        size=fm.Vector3(x=vehicle.length_m, y=vehicle.width_m, z=FEATURE_HEIGHT_M),
        color=_colour("vehicle"),
    )
    outline = _entity(stamp, BASE, "vehicle", frame_locked=True, cubes=[body])
    ring = ellipse_points(np.array([msg.x_m, msg.y_m]), msg.pose_covariance[:2, :2])
    ellipse = _entity(
        stamp, msg.header.frame_id or ODOM, "pose_ellipse",
        lines=[_line(ring, "odometry ellipse", 0.01, closed=True)],
    )  # fmt: skip
    return _scene(stamp, [outline, ellipse])


def intended_path(msg: VehicleState) -> Any:
    """Where the vehicle intends to go: its pose, then its waypoints (``odom``), each facing
    the next."""
    xy = np.vstack([[msg.x_m, msg.y_m], msg.intent_xy])
    step = np.diff(xy, axis=0)
    heading = np.arctan2(step[:, 1], step[:, 0])
    heading = np.append(heading, heading[-1:] if heading.size else [msg.yaw_rad])  # the last
    poses = [_pose(x, y, yaw) for (x, y), yaw in zip(xy.tolist(), heading.tolist(), strict=True)]
    return _fm().PosesInFrame(
        timestamp=_time(msg.header.stamp_ns), frame_id=msg.header.frame_id or ODOM, poses=poses
    )


def head_update(msg: HeadState, sensor: SensorParameters) -> Any:
    """The head (entity ``head``, following the ``head`` frame): its scan window over the
    depth of field as an outline, coloured by mode (scanning green, slewing yellow, idle
    grey, fault red), and a label with the mode and pan."""
    near, far = sensor.depth_of_field_m
    low, high = msg.window_low_rad, msg.window_high_rad
    outline = np.vstack([_arc(near, low, high), _arc(far, high, low)])
    label = f"{msg.mode} pan {math.degrees(msg.pan_rad):+.1f}°"
    if not msg.laser_on:
        label += ", laser off"
    if not msg.command_accepted and msg.command_message:
        label += f": {msg.command_message}"
    colour = msg.mode if msg.mode in COLOURS else "idle"
    entity = _entity(
        msg.header.stamp_ns, HEAD, "head", frame_locked=True,
        lines=[_line(outline, colour, 0.01, closed=True)], texts=[_text(0.3, 0.0, label, colour)],
    )  # fmt: skip
    return _scene(msg.header.stamp_ns, [entity])


def truth_update(msg: WorldTruth, vehicle: VehicleSpec) -> Any:
    """Simulation truth (``world``): the vehicle's true outline (``truth/vehicle``, white,
    labelled ``truth``, or the collision) and every mover (``truth/mover/<i>``, red) with its
    velocity arrow. The world's static walls, boxes and cylinders are not on the bus."""
    fm = _fm()
    stamp = msg.header.stamp_ns
    frame = msg.header.frame_id or WORLD
    body = fm.CubePrimitive(
        pose=_pose(msg.x_m, msg.y_m, msg.yaw_rad, z=0.5 * FEATURE_HEIGHT_M),
        size=fm.Vector3(x=vehicle.length_m, y=vehicle.width_m, z=FEATURE_HEIGHT_M),
        color=_colour("truth vehicle"),
    )
    label = "truth"
    if msg.collision:
        label = f"truth: collision ({msg.collision} moved, obstacle {msg.collision_obstacle})"
    text = _text(msg.x_m, msg.y_m, label, "not ok" if msg.collision else "label")
    meta = _metadata(
        clearance_m=f"{msg.clearance_m:.3f}", min_clearance_m=f"{msg.min_clearance_m:.3f}"
    )
    entities = [_entity(stamp, frame, "truth/vehicle", cubes=[body], texts=[text], metadata=meta)]
    for i in range(msg.mover_radius_m.size):
        x, y = (float(v) for v in msg.mover_xy[i])
        vx, vy = (float(v) for v in msg.mover_velocity_xy[i])
        parts: dict[str, list[Any]] = {
            "cylinders": [_cylinder(x, y, float(msg.mover_radius_m[i]), "truth mover")]
        }
        arrow = _arrow(x, y, vx, vy, "truth mover")
        if arrow is not None:
            parts["arrows"] = [arrow]
        entities.append(_entity(stamp, frame, f"truth/mover/{i}", **parts))
    return _scene(stamp, entities)


def truth_pose(msg: WorldTruth) -> Any:
    """The vehicle's true pose (``world``)."""
    return _fm().PoseInFrame(
        timestamp=_time(msg.header.stamp_ns), frame_id=msg.header.frame_id or WORLD,
        pose=_pose(msg.x_m, msg.y_m, msg.yaw_rad),
    )  # fmt: skip


def log_line(stamp_ns: int, level: str, source: str, text: str) -> Any:
    """A Log message; ``level`` one of Info, Warning, Error."""
    fm = _fm()
    return fm.Log(
        timestamp=_time(stamp_ns), level=getattr(fm.LogLevel, level), message=text, name=source
    )


# ---------------------------------------------------------------------------- converter
class Converter:
    """Bus messages in, the Foxglove messages they show as out.

    :meth:`convert` takes one decoded message of a topic and returns ``(channel, message)``
    pairs (each carrying the bus message's stamp). Between messages it keeps which source
    places ``base_link`` (odometry once one has arrived), the latest truth and odometry poses
    (paired into ``world → odom``), and what the log lines report changes of: a command the
    head refuses, the head's fault, the environment's ``sensor_ok``, a collision.
    ``skipped`` counts, by reason, the messages of shown topics that gave no output (a sweep
    off a uniform grid, a stamp Foxglove's time cannot hold).
    """

    def __init__(
        self, vehicle: VehicleSpec | None = None, sensor: SensorParameters | None = None
    ) -> None:
        self.vehicle = vehicle or VehicleSpec()
        self.sensor = sensor or SensorParameters()
        self.skipped: Counter[str] = Counter()
        self._odometry_seen = False
        self._odom_pose: tuple[int, tuple[float, float, float]] | None = None
        self._truth_pose: tuple[int, tuple[float, float, float]] | None = None
        self._paired_stamp: int | None = None
        self._refused_seq: int | None = None
        self._head_mode: str | None = None
        self._sensor_ok: bool | None = None
        self._collision = ""

    def convert(
        self, topic: str, msg: Message, wanted: Callable[[str], bool] | None = None
    ) -> list[Output]:
        """The Foxglove messages ``msg`` (on ``topic``) shows as, on channels ``wanted``
        (default: all). State is kept whether or not a channel is wanted."""
        if msg.header.stamp_ns >= MAX_STAMP_NS:
            self.skipped[f"{topic}: stamp past Foxglove's time range (the year 2106)"] += 1
            return []
        want = wanted or (lambda _channel: True)
        out: list[Output] = []
        offset = self.vehicle.head_offset_m
        if isinstance(msg, CalibratedScan):
            if want(SCAN):
                scan = laser_scan(msg, offset)
                if scan is None:
                    self.skipped[f"{topic}: bearings off a uniform grid (see /scan/points)"] += 1
                else:
                    out.append((SCAN, scan))
        elif isinstance(msg, FilteredScan):
            if want(SCAN_POINTS):
                out.append((SCAN_POINTS, scan_points(msg)))
        elif isinstance(msg, Features):
            if want(FEATURES):
                out.append((FEATURES, features_update(msg)))
        elif isinstance(msg, Tracks):
            if want(TRACKS):
                out.append((TRACKS, tracks_update(msg)))
        elif isinstance(msg, EnvironmentVector):
            if want(ENVIRONMENT):
                far_m = self.sensor.depth_of_field_m[1]
                out.append((ENVIRONMENT, environment_update(msg, offset, far_m)))
            out += self._sensor_log(msg, want)
        elif isinstance(msg, Odometry):
            self._odometry_seen = True
            if want(ODOMETRY):
                out.append((ODOMETRY, odometry_message(msg)))
            out += self._vehicle(msg, want)
            self._odom_pose = (msg.header.stamp_ns, (msg.x_m, msg.y_m, msg.yaw_rad))
            out += self._pair(want)
        elif isinstance(msg, VehicleState):
            if not self._odometry_seen:
                out += self._vehicle(msg, want)
            if want(VEHICLE_PATH):
                out.append((VEHICLE_PATH, intended_path(msg)))
        elif isinstance(msg, HeadState):
            if want(TF):
                out.append((TF, _fm().FrameTransforms(transforms=[head_transform(msg, offset)])))
            if want(HEAD_VIEW):
                out.append((HEAD_VIEW, head_update(msg, self.sensor)))
            out += self._head_log(msg, want)
        elif isinstance(msg, WorldTruth):
            if want(TRUTH):
                out.append((TRUTH, truth_update(msg, self.vehicle)))
            if want(TRUTH_POSE):
                out.append((TRUTH_POSE, truth_pose(msg)))
            self._truth_pose = (msg.header.stamp_ns, (msg.x_m, msg.y_m, msg.yaw_rad))
            out += self._pair(want)
            if msg.collision and not self._collision and want(LOG):
                text = f"collision: {msg.collision} moved, obstacle {msg.collision_obstacle}"
                out.append((LOG, log_line(msg.header.stamp_ns, "Error", "truth", text)))
            self._collision = msg.collision
        return out

    def _vehicle(self, msg: Odometry | VehicleState, want: Callable[[str], bool]) -> list[Output]:
        out: list[Output] = []
        if want(TF):
            out.append((TF, _fm().FrameTransforms(transforms=[base_transform(msg)])))
        if want(VEHICLE):
            out.append((VEHICLE, vehicle_update(msg, self.vehicle)))
        return out

    def _pair(self, want: Callable[[str], bool]) -> list[Output]:
        """``world → odom`` from a truth and an odometry pose of one instant, once per truth."""
        if self._truth_pose is None or self._odom_pose is None:
            return []
        truth_ns, true_pose = self._truth_pose
        odom_ns, odom_pose = self._odom_pose
        if abs(truth_ns - odom_ns) > PAIR_TOLERANCE_NS or self._paired_stamp == truth_ns:
            return []
        self._paired_stamp = truth_ns
        if not want(TF):
            return []
        x, y, yaw = world_to_odom(true_pose, odom_pose)
        transform = _transform(truth_ns, WORLD, ODOM, x, y, yaw)
        return [(TF, _fm().FrameTransforms(transforms=[transform]))]

    def _head_log(self, msg: HeadState, want: Callable[[str], bool]) -> list[Output]:
        lines: list[tuple[str, str]] = []
        if not msg.command_accepted and msg.command_seq != self._refused_seq:
            self._refused_seq = msg.command_seq
            why = msg.command_message or "no reason given"
            lines.append(("Warning", f"head refused command {msg.command_seq}: {why}"))
        if msg.mode != self._head_mode:
            if msg.mode == "fault":
                lines.append(("Error", f"head fault: {msg.command_message or 'laser off'}"))
            elif self._head_mode == "fault":
                lines.append(("Info", f"head {msg.mode} again"))
            self._head_mode = msg.mode
        if not want(LOG):
            return []
        source = msg.header.source or "head"
        return [(LOG, log_line(msg.header.stamp_ns, lvl, source, t)) for lvl, t in lines]

    def _sensor_log(self, msg: EnvironmentVector, want: Callable[[str], bool]) -> list[Output]:
        before, self._sensor_ok = self._sensor_ok, msg.sensor_ok
        if before == msg.sensor_ok or (before is None and msg.sensor_ok) or not want(LOG):
            return []
        level, text = (
            ("Info", "environment: sensor ok again")
            if msg.sensor_ok
            else ("Warning", "environment: sensor not ok (a vehicle must not move on it)")
        )
        source = msg.header.source or "planner"
        return [(LOG, log_line(msg.header.stamp_ns, level, source, text))]
