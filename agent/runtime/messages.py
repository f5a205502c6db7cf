"""Every message type of the process graph, and its wire format.

Wire format
-----------
A message is one msgpack map::

    {"type": "raw_scan/1",                    # type tag: name "/" schema version
     "header": {"stamp_ns": int, "seq": int, "frame_id": str, "source": str},
     <field>: <value>, ...}

* Scalars are msgpack numbers, booleans or strings; SI units, named in the field
  (``range_m``, ``pan_rad``, ``intensity_A``). Times are seconds as float64 (``*_s``) on the
  graph's clock, or integer nanoseconds in ``header.stamp_ns``.
* Arrays are typed binary: msgpack extension type 1 whose payload is one dtype byte
  (``d`` float64, ``f`` float32, ``q`` int64, ``i`` int32, ``B`` uint8, ``?`` bool), one
  byte for the number of dimensions, each dimension as a little-endian uint32, then the
  little-endian data in C order.
* Evolution: a new field goes last, with a default, and old readers ignore fields they do not
  know; a change that breaks old readers gets a new version number in the tag.

Decoding validates at the boundary: size limits, the type tag, every field's presence, type,
shape (arrays sharing a dimension name, such as ``n`` samples, must agree) and range. Any
failure raises :class:`agent.errors.MessageError` with a ``kind`` for counting.

Frames (REP-103): ``odom`` (the vehicle's odometry frame), ``map``/``world`` (simulation
truth), ``base_link`` (the vehicle: x forward, y left), ``head`` (the head after pan: x along
the sensor axis). Covariances are row-major ``(..., d, d)`` arrays in the units of the state
they describe.
"""

from __future__ import annotations

import dataclasses
import math
import struct
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar, TypeGuard, TypeVar, get_type_hints

import msgpack
import numpy as np
from numpy.typing import NDArray

from agent.errors import MessageError

MAX_MESSAGE_BYTES = 8 * 1024 * 1024
MAX_ARRAY_ELEMENTS = 1 << 20
MAX_STRING_CHARS = 4096
MAX_DIMENSIONS = 4
MAX_LIST_ITEMS = 4096
MAX_MAP_ITEMS = 256
MAX_NAME_CHARS = 256  # type tags, header frame ids and sources, counter names
ARRAY_EXT_CODE = 1

_DTYPES: dict[bytes, np.dtype[Any]] = {
    b"d": np.dtype("<f8"), b"f": np.dtype("<f4"), b"q": np.dtype("<i8"),
    b"i": np.dtype("<i4"), b"B": np.dtype("u1"), b"?": np.dtype("?"),
}  # fmt: skip
_CODES = {dt: code for code, dt in _DTYPES.items()}


# ------------------------------------------------------------------------------ field specs
@dataclass(frozen=True)
class Spec:
    """What a field may hold (attached as dataclass field metadata)."""

    kind: str  # "float", "int", "bool", "str", "array", "header", "dict"
    unit: str = ""
    lo: float | None = None
    hi: float | None = None
    finite: bool = True  # floats: NaN/inf refused (arrays: unless allow_nan)
    allow_nan: bool = False  # arrays: NaN marks "no value" (e.g. no reading); inf refused
    dtype: str = ""
    dims: tuple[str | int, ...] = ()
    choices: tuple[str, ...] = ()
    doc: str = ""


def _meta(spec: Spec) -> dict[str, Spec]:
    return {"spec": spec}


def f64(
    unit: str = "",
    lo: float | None = None,
    hi: float | None = None,
    default: Any = None,
    doc: str = "",
) -> Any:
    """A float field."""
    spec = Spec("float", unit, lo, hi, doc=doc)
    if default is None:
        return field(metadata=_meta(spec))
    return field(default=default, metadata=_meta(spec))


def i64(lo: int | None = None, hi: int | None = None, default: Any = None, doc: str = "") -> Any:
    spec = Spec("int", "", lo, hi, doc=doc)
    if default is None:
        return field(metadata=_meta(spec))
    return field(default=default, metadata=_meta(spec))


def boolean(default: bool | None = None, doc: str = "") -> Any:
    spec = Spec("bool", doc=doc)
    if default is None:
        return field(metadata=_meta(spec))
    return field(default=default, metadata=_meta(spec))


def text(default: str | None = None, choices: tuple[str, ...] = (), doc: str = "") -> Any:
    spec = Spec("str", choices=choices, doc=doc)
    if default is None:
        return field(metadata=_meta(spec))
    return field(default=default, metadata=_meta(spec))


def array(
    dtype: str,
    dims: tuple[str | int, ...],
    unit: str = "",
    lo: float | None = None,
    hi: float | None = None,
    allow_nan: bool = False,
    doc: str = "",
    optional: bool = False,
) -> Any:
    """An array field: ``dtype`` as numpy spells it (``f8``), ``dims`` names or sizes."""
    spec = Spec("array", unit, lo, hi, allow_nan=allow_nan, dtype=dtype, dims=dims, doc=doc)
    if optional:
        empty_shape = tuple(0 if isinstance(d, str) else d for d in dims)
        return field(
            default_factory=lambda: np.zeros(empty_shape, dtype=dtype), metadata=_meta(spec)
        )
    return field(metadata=_meta(spec))


def counters(doc: str = "") -> Any:
    """A map of counter names to non-negative integers."""
    return field(default_factory=dict, metadata=_meta(Spec("dict", doc=doc)))


# --------------------------------------------------------------------------------- header
@dataclass(frozen=True)
class Header:
    """Every message's header.

    stamp_ns : time the message's content refers to, integer nanoseconds on the graph's clock.
    seq : per-publisher, per-topic sequence number (gaps show drops).
    frame_id : the frame the content is expressed in.
    source : name of the process that produced it.
    """

    stamp_ns: int = 0
    seq: int = 0
    frame_id: str = ""
    source: str = ""

    @property
    def stamp_s(self) -> float:
        return self.stamp_ns * 1e-9


def stamp_ns(time_s: float) -> int:
    """Seconds to integer nanoseconds."""
    return round(time_s * 1e9)


# -------------------------------------------------------------------------------- registry
M = TypeVar("M", bound="Message")
REGISTRY: dict[str, type[Message]] = {}


class Message:
    """Base of every message type. Subclasses are frozen dataclasses made with :func:`message`."""

    TYPE: ClassVar[str]
    VERSION: ClassVar[int]
    header: Header

    @property
    def tag(self) -> str:
        return f"{self.TYPE}/{self.VERSION}"

    def to_wire(
        self, *, seq: int | None = None, source: str | None = None, stamp_ns: int | None = None
    ) -> bytes:
        """Encode as msgpack bytes, with the header's ``seq``, ``source`` or ``stamp_ns``
        replaced where given (a publisher's stamping, without copying the message)."""
        return encode(self, seq=seq, source=source, stamp_ns=stamp_ns)

    def with_header(self: M, **changes: Any) -> M:
        """A copy with header fields replaced (``seq``, ``source``, ...)."""
        new_header = dataclasses.replace(self.header, **changes)
        return dataclasses.replace(self, header=new_header)  # type: ignore[type-var]


def message(type_name: str, version: int) -> Callable[[type[M]], type[M]]:
    """Class decorator: register a message dataclass under ``type_name/version``.

    Apply it above ``@dataclass(frozen=True, eq=False, kw_only=True)``.
    """

    def wrap(cls: type[M]) -> type[M]:
        if not dataclasses.is_dataclass(cls):
            raise TypeError(f"{cls.__name__} must be a dataclass")
        cls.TYPE = type_name
        cls.VERSION = version
        tag = f"{type_name}/{version}"
        if tag in REGISTRY:
            raise ValueError(f"message type {tag} declared twice")
        REGISTRY[tag] = cls
        return cls

    return wrap


# ------------------------------------------------------------------------------- the types
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
    """

    header: Header
    x_m: float = f64("m")
    y_m: float = f64("m")
    yaw_rad: float = f64("rad", -4 * PI, 4 * PI)
    speed_m_s: float = f64("m/s", -5.0, 5.0)
    yaw_rate_rad_s: float = f64("rad/s", -10.0, 10.0)
    pose_covariance: FloatArray = array("f8", (3, 3), doc="x, y, yaw; m², m·rad, rad²")
    intent_xy: FloatArray = array("f8", ("k", 2), "m", doc="waypoints ahead, odom frame")


@message("wheel_command", 1)
@dataclass(frozen=True, eq=False, kw_only=True)
class WheelCommand(Message):
    """Speed and yaw rate for the differential-drive base (frame ``base_link``)."""

    header: Header
    speed_m_s: float = f64("m/s", -2.0, 2.0)
    yaw_rate_rad_s: float = f64("rad/s", -5.0, 5.0)


@message("world_truth", 1)
@dataclass(frozen=True, eq=False, kw_only=True)
class WorldTruth(Message):
    """Simulation truth: the vehicle's true pose and velocity (frame ``world``)."""

    header: Header
    x_m: float = f64("m")
    y_m: float = f64("m")
    yaw_rad: float = f64("rad", -4 * PI, 4 * PI)
    speed_m_s: float = f64("m/s", -5.0, 5.0)
    yaw_rate_rad_s: float = f64("rad/s", -10.0, 10.0)
    world_name: str = text(default="")


@message("head_command", 1)
@dataclass(frozen=True, eq=False, kw_only=True)
class HeadCommand(Message):
    """Point the head and choose the scan window (frame ``base_link``).

    The head accepts pan within ±90° and windows within ±20°; anything else it refuses with a
    :class:`HeadState` whose ``command_accepted`` is false and ``command_message`` says why.
    ``laser`` false parks the mirror and turns the laser off.
    """

    header: Header
    pan_rad: float = f64("rad", -PI, PI)
    window_low_rad: float = f64("rad", -PI / 2, PI / 2)
    window_high_rad: float = f64("rad", -PI / 2, PI / 2)
    laser: bool = boolean(default=True)


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
    scanning each beam left from, in the same frame.
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


@message("tracks", 1)
@dataclass(frozen=True, eq=False, kw_only=True)
class Tracks(Message):
    """Feature tracks (frame ``odom``): struct of arrays over ``k`` tracks.

    ``state`` (k, 4): x, y, vx, vy of the track's reference point; ``covariance`` (k, 4, 4);
    ``kind`` as in :class:`Features`; ``status``: 0 tentative, 1 confirmed, 2 coasting.
    """

    header: Header
    track_id: NDArray[np.int64] = array("i8", ("k",), lo=0)
    kind: NDArray[np.uint8] = array("u1", ("k",), lo=0, hi=3)
    status: NDArray[np.uint8] = array("u1", ("k",), lo=0, hi=2)
    state: FloatArray = array("f8", ("k", 4))
    covariance: FloatArray = array("f8", ("k", 4, 4))
    extent: FloatArray = array("f8", ("k", 4), doc="segment end points or radius, as params")
    reflectivity: FloatArray = array("f8", ("k",), lo=0.0, allow_nan=True)


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
    sensor_ok: bool = boolean()
    valid_for_s: float = f64("s", 0.0, 60.0, default=0.3)


# ------------------------------------------------------------------------------ the codec
@dataclass(frozen=True)
class _FieldPlan:
    name: str
    spec: Spec
    required: bool


_PLANS: dict[type[Message], tuple[_FieldPlan, ...]] = {}


def _plan(cls: type[Message]) -> tuple[_FieldPlan, ...]:
    """How to encode and check each field of a message type (built once per type)."""
    plan = _PLANS.get(cls)
    if plan is None:
        plan = _PLANS[cls] = _build_plan(cls)
    return plan


def _build_plan(cls: type[Message]) -> tuple[_FieldPlan, ...]:
    hints = get_type_hints(cls)
    plans = []
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        declared = Spec("header") if f.name == "header" else f.metadata.get("spec")
        if not isinstance(declared, Spec):
            raise TypeError(f"{cls.__name__}.{f.name} ({hints.get(f.name)}) has no spec")
        spec = declared
        required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        plans.append(_FieldPlan(f.name, spec, required and f.name != "header"))
    return tuple(plans)


def _wire_dtype(dtype: str) -> np.dtype[Any]:
    dt = np.dtype(dtype)
    return dt.newbyteorder("<") if dt.itemsize > 1 else dt


def _pack_array(a: NDArray[Any], dtype: str) -> msgpack.ExtType:
    dt = _wire_dtype(dtype)
    arr = np.ascontiguousarray(a, dtype=dt)
    shape = struct.pack(f"<{arr.ndim}I", *arr.shape)
    return msgpack.ExtType(ARRAY_EXT_CODE, _CODES[dt] + bytes([arr.ndim]) + shape + arr.tobytes())


def _ext_hook(code: int, data: bytes) -> Any:
    # Extension payloads are only kept here; a known field's array is parsed and checked in
    # _check, so an unknown field of a newer writer (any extension) is ignored, not refused.
    return _WireExt(code, data)


class _WireExt:
    """An extension value as received, before its field's validation."""

    __slots__ = ("code", "data")

    def __init__(self, code: int, data: bytes) -> None:
        self.code = code
        self.data = data


def _parse_array(ext: _WireExt, where: str) -> NDArray[Any]:
    """The array an extension holds (see the module docstring); MessageError if it cannot."""
    data = ext.data
    if ext.code != ARRAY_EXT_CODE:
        raise MessageError("malformed", f"{where}: unknown msgpack extension type {ext.code}")
    if len(data) < 2:
        raise MessageError("truncated", f"{where}: array header cut short")
    dtype = _DTYPES.get(data[:1])
    if dtype is None:
        raise MessageError("malformed", f"{where}: unknown array dtype code {data[:1]!r}")
    ndim = data[1]
    if ndim > MAX_DIMENSIONS:
        raise MessageError(
            "malformed", f"{where}: array of {ndim} dimensions (at most {MAX_DIMENSIONS})"
        )
    end = 2 + 4 * ndim
    if len(data) < end:
        raise MessageError("truncated", f"{where}: array shape cut short")
    shape = struct.unpack(f"<{ndim}I", data[2:end])
    if any(n > MAX_ARRAY_ELEMENTS for n in shape) or math.prod(shape) > MAX_ARRAY_ELEMENTS:
        raise MessageError(
            "oversized", f"{where}: array of shape {shape} (at most {MAX_ARRAY_ELEMENTS} elements)"
        )
    count = math.prod(shape)
    if len(data) - end != count * dtype.itemsize:
        kind = "truncated" if len(data) - end < count * dtype.itemsize else "malformed"
        raise MessageError(
            kind,
            f"{where}: array data is {len(data) - end} bytes, shape {shape} of {dtype} needs "
            f"{count * dtype.itemsize}",
        )
    return np.frombuffer(data, dtype=dtype, count=count, offset=end).reshape(shape)


def _default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return _pack_array(obj, obj.dtype.str)
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"cannot encode {type(obj).__name__}")


def encode(
    msg: Message,
    *,
    seq: int | None = None,
    source: str | None = None,
    stamp_ns: int | None = None,
) -> bytes:
    """A message as msgpack bytes (see the module docstring).

    ``seq``, ``source`` and ``stamp_ns``, where given, replace the header's on the wire.
    """
    out: dict[str, Any] = {"type": msg.tag}
    for plan in _plan(type(msg)):
        value = getattr(msg, plan.name)
        if plan.spec.kind == "header":
            h = value
            out["header"] = {
                "stamp_ns": int(h.stamp_ns if stamp_ns is None else stamp_ns),
                "seq": int(h.seq if seq is None else seq),
                "frame_id": h.frame_id,
                "source": h.source if source is None else source,
            }
        elif plan.spec.kind == "array":
            out[plan.name] = _pack_array(value, plan.spec.dtype)
        elif plan.spec.kind == "float":
            out[plan.name] = float(value)
        elif plan.spec.kind == "int":
            out[plan.name] = int(value)
        elif plan.spec.kind == "bool":
            out[plan.name] = bool(value)
        elif plan.spec.kind == "dict":
            out[plan.name] = {str(k): int(v) for k, v in value.items()}
        else:
            out[plan.name] = value
    packed: bytes = msgpack.packb(out, use_bin_type=True, default=_default)
    return packed


def _unpack(data: bytes) -> Any:
    if not isinstance(data, bytes | bytearray | memoryview):
        raise MessageError("malformed", f"expected bytes, got {type(data).__name__}")
    raw = bytes(data)  # a byte copy: sizes below are in bytes whatever the view's item size
    if len(raw) > MAX_MESSAGE_BYTES:
        raise MessageError("oversized", f"{len(raw)} bytes (at most {MAX_MESSAGE_BYTES})")
    if not raw:
        raise MessageError("truncated", "empty message")
    unpacker = msgpack.Unpacker(
        ext_hook=_ext_hook, raw=False, strict_map_key=True,
        max_buffer_size=MAX_MESSAGE_BYTES, max_str_len=MAX_STRING_CHARS * 4,
        max_bin_len=MAX_MESSAGE_BYTES, max_array_len=MAX_LIST_ITEMS, max_map_len=MAX_MAP_ITEMS,
        max_ext_len=MAX_MESSAGE_BYTES,
    )  # fmt: skip
    try:
        unpacker.feed(raw)
        obj = unpacker.unpack()
    except msgpack.OutOfData:
        raise MessageError("truncated", "message ends before its content does") from None
    except MessageError:
        raise
    except ValueError as exc:
        # msgpack reports a length over one of the limits set above as a ValueError naming
        # the limit ("... exceeds max_str_len(...)"); anything else is a format error.
        kind = "oversized" if "exceeds max_" in str(exc) else "malformed"
        raise MessageError(kind, f"not valid msgpack ({exc})") from None
    except Exception as exc:  # msgpack raises several types for corrupt input
        raise MessageError("malformed", f"not valid msgpack ({type(exc).__name__})") from None
    if unpacker.tell() != len(raw):
        raise MessageError("malformed", f"{len(raw) - unpacker.tell()} bytes after the message")
    return obj


def peek_type(data: bytes) -> str:
    """The type tag of an encoded message, validated only as far as needed."""
    obj = _unpack(data)
    if not isinstance(obj, dict) or not isinstance(obj.get("type"), str):
        raise MessageError("malformed", "not a map with a string 'type'")
    return str(obj["type"])


def decode(data: bytes, expect: type[M] | None = None) -> M | Message:
    """Decode and validate a message; raise :class:`MessageError` if it is unusable.

    With ``expect``, a message of another type is an error (kind ``unknown_type``).
    """
    obj = _unpack(data)
    if not isinstance(obj, dict):
        raise MessageError("malformed", f"top level is {type(obj).__name__}, not a map")
    tag = obj.get("type")
    if not isinstance(tag, str):
        raise MessageError("malformed", "missing or non-string 'type'")
    if len(tag) > MAX_NAME_CHARS:
        raise MessageError("oversized", f"type tag longer than {MAX_NAME_CHARS}")
    cls = REGISTRY.get(tag)
    if cls is None:
        name = tag.partition("/")[0]
        known = [t for t in REGISTRY if t.partition("/")[0] == name]
        if known:
            raise MessageError("wrong_version", f"{tag!r}: this program reads {', '.join(known)}")
        raise MessageError("unknown_type", f"unknown message type {tag!r}")
    if expect is not None and cls is not expect:
        raise MessageError("unknown_type", f"expected {expect.TYPE}, got {tag!r}")
    values: dict[str, Any] = {}
    sizes: dict[str, int] = {}
    for plan in _plan(cls):
        if plan.name not in obj:
            if plan.spec.kind == "header":
                raise MessageError("malformed", f"{tag}: missing header")
            if plan.required:
                raise MessageError("malformed", f"{tag}: missing field {plan.name!r}")
            continue
        values[plan.name] = _check(tag, plan, obj[plan.name], sizes)
    return cls(**values)


def _check(tag: str, plan: _FieldPlan, raw: Any, sizes: dict[str, int]) -> Any:
    spec, name = plan.spec, plan.name
    where = f"{tag}: field {name!r}"
    if spec.kind == "header":
        if not isinstance(raw, dict):
            raise MessageError("malformed", f"{tag}: header is not a map")
        stamp, seq = raw.get("stamp_ns"), raw.get("seq")
        frame, source = raw.get("frame_id"), raw.get("source")
        if not (_is_int(stamp) and _is_int(seq)):
            raise MessageError("malformed", f"{tag}: header stamp_ns and seq must be integers")
        if not (isinstance(frame, str) and isinstance(source, str)):
            raise MessageError("malformed", f"{tag}: header frame_id and source must be strings")
        if len(frame) > MAX_NAME_CHARS or len(source) > MAX_NAME_CHARS:
            raise MessageError("oversized", f"{tag}: header names longer than {MAX_NAME_CHARS}")
        if seq < 0 or stamp < 0:
            raise MessageError("out_of_range", f"{tag}: header stamp and seq must be >= 0")
        return Header(stamp_ns=stamp, seq=seq, frame_id=frame, source=source)
    if spec.kind == "array":
        if not isinstance(raw, _WireExt):
            raise MessageError("malformed", f"{where} must be a typed array")
        arr = _parse_array(raw, where)
        if arr.dtype != _wire_dtype(spec.dtype):
            raise MessageError("malformed", f"{where} must be {spec.dtype}, got {arr.dtype}")
        if arr.ndim != len(spec.dims):
            raise MessageError(
                "malformed", f"{where} must have {len(spec.dims)} dimensions, got shape {arr.shape}"
            )
        for dim, size in zip(spec.dims, arr.shape, strict=True):
            if isinstance(dim, int):
                if size != dim:
                    raise MessageError("malformed", f"{where} has shape {arr.shape}")
            elif sizes.setdefault(dim, size) != size:
                raise MessageError(
                    "malformed", f"{where} has {size} along '{dim}', other fields have {sizes[dim]}"
                )
        if arr.size:
            _check_values(where, arr, spec)
        arr = arr.copy()  # own, writable memory, independent of the receive buffer
        arr.flags.writeable = False
        return arr
    if spec.kind == "float":
        if isinstance(raw, bool) or not isinstance(raw, int | float):
            raise MessageError("malformed", f"{where} must be a number")
        value = float(raw)
        if not math.isfinite(value):
            raise MessageError("out_of_range", f"{where} is not finite")
        _range(where, value, spec)
        return value
    if spec.kind == "int":
        if isinstance(raw, bool) or not isinstance(raw, int):
            raise MessageError("malformed", f"{where} must be an integer")
        _range(where, raw, spec)
        return raw
    if spec.kind == "bool":
        if not isinstance(raw, bool):
            raise MessageError("malformed", f"{where} must be true or false")
        return raw
    if spec.kind == "str":
        if not isinstance(raw, str):
            raise MessageError("malformed", f"{where} must be a string")
        if len(raw) > MAX_STRING_CHARS:
            raise MessageError("oversized", f"{where} longer than {MAX_STRING_CHARS}")
        if spec.choices and raw not in spec.choices:
            raise MessageError("out_of_range", f"{where} must be one of {spec.choices}")
        return raw
    if spec.kind == "dict":
        if not isinstance(raw, dict) or not all(
            isinstance(k, str) and _is_int(v) and v >= 0 for k, v in raw.items()
        ):
            raise MessageError("malformed", f"{where} must map names to counts >= 0")
        if any(len(k) > MAX_NAME_CHARS for k in raw):
            raise MessageError("oversized", f"{where}: a name longer than {MAX_NAME_CHARS}")
        return dict(raw)
    raise MessageError("malformed", f"{where}: unsupported field kind {spec.kind}")


def _check_values(where: str, arr: NDArray[Any], spec: Spec) -> None:
    """Refuse a non-empty array holding inf (or NaN, unless allowed) or values out of range.

    Two reductions, the least and the greatest value, answer every check: ``fmin``/``fmax``
    skip NaN where it is allowed (it marks "no value"), ``min``/``max`` carry it where it is
    not. Masks per check (isfinite, below, above) took twice as long per message.
    """
    if arr.dtype.kind == "f" and spec.allow_nan:
        least, greatest = (
            float(np.fmin.reduce(arr, axis=None)),
            float(np.fmax.reduce(arr, axis=None)),
        )
        if math.isnan(least):  # every value NaN: nothing to range-check
            return
    else:
        least, greatest = arr.min().item(), arr.max().item()
    if arr.dtype.kind == "f" and not (math.isfinite(least) and math.isfinite(greatest)):
        raise MessageError("out_of_range", f"{where} holds non-finite values")
    if (spec.lo is not None and least < spec.lo) or (spec.hi is not None and greatest > spec.hi):
        raise MessageError("out_of_range", f"{where} outside [{spec.lo}, {spec.hi}]")


def _is_int(value: Any) -> TypeGuard[int]:
    return isinstance(value, int) and not isinstance(value, bool)


def _range(where: str, value: float, spec: Spec) -> None:
    if (spec.lo is not None and value < spec.lo) or (spec.hi is not None and value > spec.hi):
        raise MessageError("out_of_range", f"{where} = {value} outside [{spec.lo}, {spec.hi}]")


def message_types() -> Mapping[str, type[Message]]:
    """Every registered message type, by tag."""
    return dict(REGISTRY)
