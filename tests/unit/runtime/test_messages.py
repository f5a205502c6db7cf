"""Tests of agent.runtime.messages and agent.runtime.topics: the bus's message types and
their wire format.

Round trips, golden bytes, size limits at their boundaries, every error kind on purpose,
deterministic fuzzing of the decoder, the topic registry, and docs/interface.md kept true.

Golden files: ``REGENERATE_GOLDEN=1 pytest tests/unit/runtime/test_messages.py -k golden`` rewrites
``tests/data/golden/<type>.msgpack`` from the deterministic examples below (and skips, saying
so); without it the test compares the encoder's bytes with the files byte for byte.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import struct
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import numpy.typing as npt
import pytest

from agent.errors import MessageError
from agent.runtime import messages as m, topics

pytestmark = pytest.mark.filterwarnings("error")

REPO = Path(__file__).resolve().parents[3]
GOLDEN = REPO / "tests" / "data" / "golden"
INTERFACE_DOC = REPO / "docs" / "interface.md"
TAGS = sorted(m.REGISTRY)
KINDS = MessageError.KINDS

FloatArray = npt.NDArray[np.float64]


# --------------------------------------------------------------------------------------------
# Examples: one fully populated, valid, deterministic message of every type
# --------------------------------------------------------------------------------------------
# Values are built with exact binary fractions and + - * / only (no RNG, no sin/exp), so the
# golden bytes cannot depend on the numpy version or the machine's SIMD instructions.

N_SAMPLES = 256
STAMP_NS = 1_767_225_600_125_000_000  # 2026-01-01T00:00:00.125Z
SAMPLE_DT_S = 2.0**-12  # 256 samples in 62.5 ms
NAN = float("nan")


def _header(frame_id: str, source: str, seq: int = 41) -> m.Header:
    return m.Header(stamp_ns=STAMP_NS, seq=seq, frame_id=frame_id, source=source)


def _diag_stack(*diagonals: tuple[float, ...]) -> FloatArray:
    """A (k, d, d) stack of diagonal covariances."""
    return np.stack([np.diag(np.array(d, dtype=np.float64)) for d in diagonals])


def _sweep() -> dict[str, Any]:
    """Per-sample arrays of one 256-sample sweep, shared by the scan examples."""
    i = np.arange(N_SAMPLES, dtype=np.float64)
    angle = (i - 127.5) / 256.0 * 0.6875  # ±0.34 rad, a ±19.7° window
    pulse_1 = np.maximum(0.0, 1.0 - np.abs(i - 128.0) / 32.0)
    pulse_2 = np.maximum(0.0, 1.0 - np.abs(i - 120.0) / 32.0)
    seen = np.abs(i - 124.0) < 64.0  # samples with a reading
    range_m = np.where(seen, 1.0 + np.abs(i - 124.0) / 128.0, NAN)
    return {
        "time_s": STAMP_NS // 10**9 + 0.125 + i * SAMPLE_DT_S,
        "angle": angle,
        "pan": np.full(N_SAMPLES, 0.5),
        "i1": 2.0**-22 + 2.0**-18 * pulse_1,
        "i2": 2.0**-22 + 2.0**-18 * pulse_2,
        "seen": seen,
        "range": range_m,
    }


def _heartbeat() -> m.Heartbeat:
    return m.Heartbeat(
        header=_header("", "calibration"),
        process="calibration",
        pid=4242,
        state="running",
        counters={"received": 1200, "published": 1198, "dropped_malformed": 2},
    )


def _stop() -> m.Stop:
    return m.Stop(header=_header("", "launcher", seq=0), reason="operator", process="tracker")


def _vehicle_state() -> m.VehicleState:
    return m.VehicleState(
        header=_header("odom", "controller"),
        x_m=12.5,
        y_m=-3.25,
        yaw_rad=0.75,
        speed_m_s=0.375,
        yaw_rate_rad_s=-0.125,
        pose_covariance=np.array(
            [[0.0025, 0.0005, 0.0], [0.0005, 0.0025, 0.0], [0.0, 0.0, 0.0004]]
        ),
        intent_xy=np.array([[13.0, -3.0], [13.5, -2.75], [14.0, -2.5]]),
        watch_xy=np.array([[13.25, -1.5], [13.25, -1.25]]),
    )


def _wheel_command() -> m.WheelCommand:
    return m.WheelCommand(
        header=_header("base_link", "planner"), speed_m_s=0.375, yaw_rate_rad_s=0.25
    )


def _world_truth() -> m.WorldTruth:
    return m.WorldTruth(
        header=_header("world", "simulator"),
        x_m=12.53125,
        y_m=-3.234375,
        yaw_rad=0.7578125,
        speed_m_s=0.40625,
        yaw_rate_rad_s=-0.1171875,
        world_name="corridor",
        mover_xy=np.array([[14.0, -2.5], [11.25, -4.0]]),
        mover_velocity_xy=np.array([[0.25, -0.125], [0.0, 0.5]]),
        mover_radius_m=np.array([0.2, 0.125]),
    )


def _odometry() -> m.Odometry:
    return m.Odometry(
        header=_header("odom", "simulator"),
        x_m=12.5,
        y_m=-3.25,
        yaw_rad=0.75,
        speed_m_s=0.375,
        yaw_rate_rad_s=-0.125,
        pose_covariance=np.array(
            [[0.0025, 0.0005, 0.0], [0.0005, 0.0025, 0.0], [0.0, 0.0, 0.0004]]
        ),
        distance_m=21.75,
    )


def _head_command() -> m.HeadCommand:
    return m.HeadCommand(
        header=_header("base_link", "planner"),
        pan_rad=0.5,
        window_low_rad=-0.3125,
        window_high_rad=0.3125,
        laser=True,
        utility_bits=12.5,
        cost_s=0.6875,
    )


def _head_state() -> m.HeadState:
    return m.HeadState(
        header=_header("base_link", "head"),
        pan_rad=0.484375,
        pan_rate_rad_s=1.5,
        target_pan_rad=0.5,
        window_low_rad=-0.3125,
        window_high_rad=0.3125,
        laser_on=True,
        mode="slewing",
        command_seq=17,
        command_accepted=False,
        command_message="window -25.0 deg outside +-20 deg",
        sweeps=1234,
    )


def _raw_scan() -> m.RawScan:
    s = _sweep()
    return m.RawScan(
        header=_header("head", "head"),
        time_s=s["time_s"],
        mirror_angle_rad=s["angle"],
        pan_rad=s["pan"],
        current_1_A=s["i1"],
        current_2_A=s["i2"],
        direction=1,
        sweep_index=1234,
    )


def _calibrated_scan() -> m.CalibratedScan:
    s = _sweep()
    seen = s["seen"]
    return m.CalibratedScan(
        header=_header("head", "calibration"),
        time_s=s["time_s"] - 2.0**-14,
        scan_angle_rad=s["angle"],
        pan_rad=s["pan"],
        image_position_norm=np.where(seen, (s["range"] - 1.5) / 2.0, NAN),
        intensity_A=s["i1"] + s["i2"],
        range_m=s["range"],
        sigma_m=np.where(seen, 2.0**-10 * s["range"] * s["range"], NAN),
        direction=-1,
        sweep_index=1234,
        scan_angle_sigma_rad=2.0**-12,
    )


def _filtered_scan() -> m.FilteredScan:
    s = _sweep()
    seen = s["seen"]
    n = N_SAMPLES
    points = np.stack([s["range"], s["range"] * s["angle"]], axis=1)
    covariance = np.where(
        seen[:, None, None], np.array([[2.0**-20, 0.0], [0.0, 2.0**-18]]), NAN
    ) * np.ones((n, 1, 1))
    segment = np.where(seen, (np.arange(n) - 60) // 48, -1).astype(np.int32)
    return m.FilteredScan(
        header=_header("base_link", "filter"),
        points_xy=points,
        covariance=covariance,
        origin_xy=np.tile([0.25, 0.0], (n, 1)),
        scan_angle_rad=s["angle"],
        intensity_A=s["i1"] + s["i2"],
        range_m=s["range"],
        sigma_m=np.where(seen, 2.0**-10, NAN),
        flag=np.where(seen, 0, 3).astype(np.uint8),
        segment=segment,
        sweep_index=7,
        motion_compensated=True,
        beam_rad=s["angle"] + 0.25,
    )


def _features() -> m.Features:
    nan = NAN
    return m.Features(
        header=_header("base_link", "features"),
        kind=np.array([0, 1, 3], dtype=np.uint8),
        params=np.array([[0.25, 1.5, nan], [1.0, -0.5, nan], [1.25, 0.5, 0.125]]),
        covariance=np.array(
            [
                [[2.0**-16, 0.0, nan], [0.0, 2.0**-14, nan], [nan, nan, nan]],
                [[2.0**-14, 0.0, nan], [0.0, 2.0**-14, nan], [nan, nan, nan]],
                np.eye(3) * 2.0**-12,
            ]
        ),
        endpoints=np.array(
            [[[1.5, -0.5], [1.5, 0.5]], [[nan, nan], [nan, nan]], [[nan, nan], [nan, nan]]]
        ),
        nearer_side=np.array([0, 0, 0], dtype=np.int32),
        reflectivity=np.array([1.0, nan, 0.5]),
        sweep_index=7,
    )


def _nan_beyond(covariance: FloatArray, dofs: tuple[int, ...]) -> FloatArray:
    """NaN in each (d, d) block beyond its first ``dof`` rows and columns."""
    out = covariance.copy()
    for i, dof in enumerate(dofs):
        out[i, dof:, :] = NAN
        out[i, :, dof:] = NAN
    return out


def _tracks() -> m.Tracks:
    return m.Tracks(
        header=_header("odom", "tracker"),
        track_id=np.array([3, 7, 12], dtype=np.int64),
        kind=np.array([0, 1, 3], dtype=np.uint8),
        status=np.array([1, 2, 0], dtype=np.uint8),
        state=np.array(
            [[13.5, -3.5, 0.0, 0.0], [13.75, -2.625, 0.0, 0.0], [14.25, -3.375, 0.25, -0.125]]
        ),
        covariance=_diag_stack((1e-4, 1e-4, 1e-3, 1e-3), (2e-4, 2e-4, 1e-3, 1e-3), (1e-3,) * 4),
        params=np.array([[0.5, 4.75, NAN], [13.75, -2.625, NAN], [14.25, -3.375, 0.125]]),
        params_covariance=_nan_beyond(
            _diag_stack((1e-4, 1e-3, 1e-3), (2e-4, 2e-4, 1e-3), (1e-3,) * 3), (2, 2, 3)
        ),
        extent=np.array([[13.0, -4.0, 14.0, -3.0], [0.0] * 4, [0.125, 0.0, 0.0, 0.0]]),
        end_seen=np.array([[1, 0], [0, 0], [0, 0]], dtype=np.uint8),
        reflectivity=np.array([1.0, 0.8125, NAN]),
        moving_probability=np.array([0.0, 0.0, 0.875]),
        last_seen_ns=np.array([STAMP_NS, STAMP_NS - 100_000_000, STAMP_NS], dtype=np.int64),
        hits=np.array([12, 40, 3], dtype=np.int64),
        information_bits=np.array([14.2, 31.7, 2.5]),
    )


def _environment() -> m.EnvironmentVector:
    bearings = (np.arange(9) - 4.0) / 8.0 * 0.6875
    return m.EnvironmentVector(
        header=_header("odom", "environment"),
        obstacle_id=np.array([3, 7, 12], dtype=np.int64),
        kind=np.array([0, 1, 4], dtype=np.uint8),
        position_xy=np.array([[13.5, -3.5], [13.75, -2.625], [14.25, -3.375]]),
        velocity_xy=np.array([[0.0, 0.0], [0.0, 0.0], [0.25, -0.125]]),
        covariance=_diag_stack((1e-4, 1e-4, 1e-3, 1e-3), (2e-4, 2e-4, 1e-3, 1e-3), (1e-3,) * 4),
        extent=np.array([[13.0, -4.0, 14.0, -3.0], [0.0] * 4, [0.0] * 4]),
        reflectivity=np.array([1.0, 0.8125, NAN]),
        free_bearing_rad=bearings,
        free_range_m=np.array([1.5, 1.625, 1.75, 0.0, 2.5, 2.5, 2.25, 1.0, 0.875]),
        free_far_m=np.array([1.5, 1.625, 1.75, 1.875, 2.5, 2.5, 2.25, 1.0, 0.875]),
        free_far_from_m=0.55,
        free_end_hit=np.array([1, 0, 1, 0, 0, 0, 0, 1, 1], dtype=np.uint8),
        scan_window_rad=np.array([-0.375, 0.3125]),
        scan_dark_m=np.array([0.0, 0.0, 0.0, 2.5, 2.5, 1.25, 0.0, 0.0, 0.0]),
        seen_range_m=np.array([1.625, 1.75, 1.875, 0.0, 2.5, 2.5, 2.375, 1.125, 1.0]),
        seen_far_m=np.array([1.625, 1.75, 1.875, 2.0, 2.5, 2.5, 2.375, 1.125, 1.0]),
        seen_end_hit=np.array([1, 0, 1, 0, 0, 0, 0, 1, 1], dtype=np.uint8),
        across_sigma_m=np.array([0.0, 0.00390625, 0.0]),
        maintained=np.array([1, 0, 1], dtype=np.uint8),
        seen_age_s=np.array([0.0, 0.1, 2.5]),
        sensor_ok=True,
        valid_for_s=0.3,
    )


EXAMPLES: dict[type[m.Message], Callable[[], m.Message]] = {
    m.Heartbeat: _heartbeat,
    m.Stop: _stop,
    m.VehicleState: _vehicle_state,
    m.WheelCommand: _wheel_command,
    m.WorldTruth: _world_truth,
    m.Odometry: _odometry,
    m.HeadCommand: _head_command,
    m.HeadState: _head_state,
    m.RawScan: _raw_scan,
    m.CalibratedScan: _calibrated_scan,
    m.FilteredScan: _filtered_scan,
    m.Features: _features,
    m.Tracks: _tracks,
    m.EnvironmentVector: _environment,
}


def example(tag: str) -> m.Message:
    """The example message of a registered type."""
    return EXAMPLES[m.REGISTRY[tag]]()


@pytest.fixture(params=TAGS)
def example_message(request: pytest.FixtureRequest) -> m.Message:
    """One fully populated, valid message of each registered type, in turn."""
    return example(request.param)


# --------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------

_WIRE_CODES = {"f8": b"d", "f4": b"f", "i8": b"q", "i4": b"i", "u1": b"B", "b1": b"?"}


def typed_array(values: Any, dtype: str = "f8", code: bytes | None = None) -> msgpack.ExtType:
    """The documented typed-array extension, built independently of agent.runtime.messages."""
    arr = np.ascontiguousarray(values, dtype=np.dtype(dtype).newbyteorder("<"))
    code = _WIRE_CODES[dtype] if code is None else code
    shape = struct.pack(f"<{arr.ndim}I", *arr.shape)
    return msgpack.ExtType(1, code + bytes([arr.ndim]) + shape + arr.tobytes())


def raw_ext(code: bytes, shape: tuple[int, ...], data: bytes, ndim: int | None = None) -> Any:
    """A typed-array extension with any header and payload, consistent or not."""
    ndim = len(shape) if ndim is None else ndim
    return msgpack.ExtType(1, code + bytes([ndim]) + struct.pack(f"<{len(shape)}I", *shape) + data)


def to_map(msg: m.Message) -> dict[str, Any]:
    """A message's wire map, typed arrays left as ``msgpack.ExtType``, ready to tamper with."""
    obj = msgpack.unpackb(msg.to_wire(), raw=False, ext_hook=msgpack.ExtType)
    assert isinstance(obj, dict)
    return obj


def pack(obj: Any) -> bytes:
    packed: bytes = msgpack.packb(obj, use_bin_type=True)
    return packed


def tampered(msg: m.Message, **changes: Any) -> bytes:
    """A message's bytes with wire fields replaced (a value of ``DELETE`` removes the field)."""
    obj = to_map(msg)
    for name, value in changes.items():
        if value is DELETE:
            del obj[name]
        else:
            obj[name] = value
    return pack(obj)


DELETE = object()


def kind_of(data: bytes, expect: type[m.Message] | None = None) -> str:
    """The error kind of decoding ``data``, or "ok"."""
    try:
        m.decode(data, expect)
    except MessageError as exc:
        return exc.kind
    return "ok"


def assert_kind(data: bytes, kind: str, needle: str = "") -> MessageError:
    with pytest.raises(MessageError) as info:
        m.decode(data)
    assert info.value.kind == kind, str(info.value)
    assert needle in str(info.value)
    return info.value


def assert_messages_equal(got: m.Message, want: m.Message) -> None:
    """Same type and every field equal (arrays: dtype, shape and values, NaN equal to NaN)."""
    assert type(got) is type(want)
    for f in dataclasses.fields(want):  # type: ignore[arg-type]
        a, b = getattr(got, f.name), getattr(want, f.name)
        if isinstance(b, np.ndarray):
            assert isinstance(a, np.ndarray), f.name
            assert a.dtype == np.dtype(b.dtype).newbyteorder("<"), f.name
            assert a.shape == b.shape, f.name
            np.testing.assert_array_equal(a, b, err_msg=f.name, strict=True)
        else:
            assert type(a) is type(b), f.name
            assert a == b, f.name


def array_fields(cls: type[m.Message]) -> list[str]:
    return [
        f.name
        for f in dataclasses.fields(cls)  # type: ignore[arg-type]
        if f.name != "header" and f.metadata["spec"].kind == "array"
    ]


# --------------------------------------------------------------------------------------------
# Examples and round trips
# --------------------------------------------------------------------------------------------


def test_every_registered_type_has_an_example_and_it_is_fully_populated() -> None:
    assert set(EXAMPLES) == set(m.REGISTRY.values())
    for tag in TAGS:
        msg = example(tag)
        assert msg.tag == tag
        for name in array_fields(type(msg)):
            assert getattr(msg, name).size > 0, f"{tag}.{name} is empty"
    assert example("raw_scan/1").time_s.shape == (N_SAMPLES,)  # type: ignore[attr-defined]
    for tag in ("features/1", "tracks/2", "environment/1"):
        assert example(tag).kind.shape == (3,)  # type: ignore[attr-defined]
    assert example("vehicle_state/1").intent_xy.shape == (3, 2)  # type: ignore[attr-defined]


def test_messages_are_keyword_only_and_frozen(example_message: m.Message) -> None:
    with pytest.raises(dataclasses.FrozenInstanceError):
        example_message.header = m.Header()  # type: ignore[misc]
    with pytest.raises(TypeError):
        type(example_message)(m.Header())  # type: ignore[call-arg]


def test_round_trip_is_field_by_field_equal(example_message: m.Message) -> None:
    wire = example_message.to_wire()
    assert wire == m.encode(example_message)
    decoded = m.decode(wire)
    assert_messages_equal(decoded, example_message)
    assert decoded.header == example_message.header
    assert m.decode(wire, expect=type(example_message)).tag == example_message.tag
    assert m.peek_type(wire) == example_message.tag
    assert decoded.to_wire() == wire  # decoding and encoding again changes nothing


def test_round_trip_keeps_nan_where_allowed() -> None:
    calibrated = m.decode(_calibrated_scan().to_wire())
    assert isinstance(calibrated, m.CalibratedScan)
    for name in ("range_m", "sigma_m", "image_position_norm"):
        values = getattr(calibrated, name)
        assert np.isnan(values).sum() == (~_sweep()["seen"]).sum() > 0, name
    env = m.decode(_environment().to_wire())
    assert isinstance(env, m.EnvironmentVector)
    assert np.isnan(env.reflectivity[2])


def test_decoded_arrays_are_read_only(example_message: m.Message) -> None:
    decoded = m.decode(example_message.to_wire())
    for name in array_fields(type(decoded)):
        values = getattr(decoded, name)
        assert not values.flags.writeable, name
        with pytest.raises(ValueError, match="read-only"):
            values[...] = 0


def test_expect_refuses_every_other_type(example_message: m.Message) -> None:
    wire = example_message.to_wire()
    for other in m.REGISTRY.values():
        if other is type(example_message):
            continue
        with pytest.raises(MessageError) as info:
            m.decode(wire, expect=other)
        assert info.value.kind == "unknown_type"
        assert other.TYPE in str(info.value)


def test_encoder_follows_the_documented_array_format() -> None:
    """The module's encoder agrees with an independent implementation of its docstring."""
    vs = _vehicle_state()
    obj = to_map(vs)
    assert list(obj)[:2] == ["type", "header"]
    assert obj["pose_covariance"] == typed_array(vs.pose_covariance)
    assert obj["intent_xy"] == typed_array(vs.intent_xy)
    fs = _filtered_scan()
    obj = to_map(fs)
    assert obj["flag"] == typed_array(fs.flag, "u1")
    assert obj["segment"] == typed_array(fs.segment, "i4")
    assert obj["covariance"].data[:14] == b"d\x03" + struct.pack("<3I", N_SAMPLES, 2, 2)


def test_decoder_accepts_any_byte_buffer() -> None:
    wire = _heartbeat().to_wire()
    for data in (wire, bytearray(wire), memoryview(wire)):
        assert_messages_equal(m.decode(data), _heartbeat())  # type: ignore[arg-type]
    assert_kind("not bytes", "malformed")  # type: ignore[arg-type]


# --------------------------------------------------------------------------------------------
# Golden bytes
# --------------------------------------------------------------------------------------------


def golden_path(tag: str) -> Path:
    return GOLDEN / f"{m.REGISTRY[tag].TYPE}.msgpack"


@pytest.mark.parametrize("tag", TAGS)
def test_golden_bytes(tag: str) -> None:
    """Encoding is frozen: a change of the bytes on the wire must be deliberate."""
    wire = example(tag).to_wire()
    path = golden_path(tag)
    if os.environ.get("REGENERATE_GOLDEN") == "1":
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(wire)
        pytest.skip(f"REGENERATE_GOLDEN=1: wrote {path.relative_to(REPO)} ({len(wire)} bytes)")
    assert path.is_file(), f"{path} missing: run with REGENERATE_GOLDEN=1 to write it"
    golden = path.read_bytes()
    if wire != golden:
        at = next(
            (i for i, (a, b) in enumerate(zip(wire, golden, strict=False)) if a != b),
            min(len(wire), len(golden)),
        )
        pytest.fail(
            f"{tag}: encoding changed at byte {at} ({len(wire)} bytes now, {len(golden)} in "
            f"{path.name}): now {wire[at : at + 16].hex(' ')}, was {golden[at : at + 16].hex(' ')}"
            "; if deliberate (and compatible, or with a new version), REGENERATE_GOLDEN=1"
        )
    assert_messages_equal(m.decode(golden), example(tag))  # old bytes still read the same


def test_golden_files_are_exactly_the_registered_types() -> None:
    if os.environ.get("REGENERATE_GOLDEN") == "1":
        pytest.skip("REGENERATE_GOLDEN=1")
    names = {p.name for p in GOLDEN.glob("*.msgpack")}
    assert names == {golden_path(tag).name for tag in TAGS}


# --------------------------------------------------------------------------------------------
# Limits, at their boundaries
# --------------------------------------------------------------------------------------------


def _padded_heartbeat(total_bytes: int) -> bytes:
    """A valid heartbeat whose unknown ``pad`` field makes it exactly ``total_bytes`` long."""
    obj = to_map(_heartbeat())
    overhead = len(pack({**obj, "pad": b"x" * 70_000})) - 70_000  # bin32 header from 64 KiB on
    data = pack({**obj, "pad": b"x" * (total_bytes - overhead)})
    assert len(data) == total_bytes
    return data


def test_message_size_limit() -> None:
    at_limit = _padded_heartbeat(m.MAX_MESSAGE_BYTES)
    assert kind_of(at_limit) != "oversized"
    assert kind_of(at_limit) == "ok"  # the extra field is ignored
    assert_kind(_padded_heartbeat(m.MAX_MESSAGE_BYTES + 1), "oversized")
    assert_kind(b"\x00" * (m.MAX_MESSAGE_BYTES + 1), "oversized")  # before any parsing


def test_array_element_limit() -> None:
    # Checked on a known field (unknown fields are ignored whole): filtered_scan's uint8 flags.
    limit = m.MAX_ARRAY_ELEMENTS
    at_limit = tampered(_filtered_scan(), flag=raw_ext(b"B", (limit,), bytes(limit)))
    assert kind_of(at_limit) != "oversized"  # passes the limit (then its n disagrees)
    too_many = tampered(_filtered_scan(), flag=raw_ext(b"B", (limit + 1,), bytes(limit + 1)))
    assert_kind(too_many, "oversized", "elements")
    # the count is the product of the dimensions
    square = raw_ext(b"d", (1024, 1025, 2), bytes(8 * 1024 * 1025 * 2 // 8))
    assert_kind(tampered(_filtered_scan(), points_xy=square), "oversized")
    # refused from the shape alone, before looking for the data
    huge = raw_ext(b"d", (1 << 16, 1 << 16, 1 << 16), b"")
    assert_kind(tampered(_filtered_scan(), covariance=huge), "oversized")
    zero_but_huge = raw_ext(b"d", (0, (1 << 32) - 1, (1 << 32) - 1), b"")
    assert_kind(tampered(_filtered_scan(), covariance=zero_but_huge), "oversized")


def test_unknown_fields_may_hold_only_well_formed_typed_arrays() -> None:
    # Forward compatibility: a newer writer's extra field is skipped if it holds a typed array
    # of any dtype and shape, but no other extension is taken anywhere (tests/unit/runtime/
    # test_wire_limits.py has the rest).
    ok = raw_ext(b"q", (2, 1), bytes(16))
    assert isinstance(m.decode(tampered(_heartbeat(), extra=ok)), m.Heartbeat)
    for extra, kind in (
        (msgpack.ExtType(9, b"??"), "malformed"),
        (raw_ext(b"h", (1,), b"\x00\x00"), "malformed"),
        (raw_ext(b"d", (1,) * 9, bytes(8)), "malformed"),
        (raw_ext(b"B", (1 << 21,), b""), "oversized"),
        (raw_ext(b"d", (3,), bytes(16)), "truncated"),
    ):
        assert_kind(tampered(_heartbeat(), extra=extra), kind, "field 'extra'")


def test_string_limit() -> None:
    limit = m.MAX_STRING_CHARS
    assert kind_of(tampered(_heartbeat(), process="p" * limit)) == "ok"
    assert kind_of(tampered(_heartbeat(), process="€" * limit)) == "ok"  # characters, not bytes
    assert_kind(tampered(_heartbeat(), process="p" * (limit + 1)), "oversized")
    assert_kind(tampered(_heartbeat(), process="€" * (limit + 1)), "oversized")
    decoded = m.decode(tampered(_heartbeat(), process="€" * limit))
    assert isinstance(decoded, m.Heartbeat)
    assert decoded.process == "€" * limit


def test_dimension_limit() -> None:
    limit = m.MAX_DIMENSIONS
    at_limit = raw_ext(b"d", (1,) * limit, struct.pack("<d", 1.0))
    error = assert_kind(tampered(_vehicle_state(), pose_covariance=at_limit), "malformed")
    assert "must have 2 dimensions" in str(error)  # past the limit check, refused for its shape
    for ndim in (limit + 1, 255):
        beyond = raw_ext(b"d", (1,) * ndim, struct.pack("<d", 1.0))
        assert_kind(
            tampered(_vehicle_state(), pose_covariance=beyond), "malformed", "dimensions (at most"
        )


def test_msgpack_container_limits() -> None:
    assert_kind(tampered(_heartbeat(), counters={f"c{i}": i for i in range(300)}), "oversized")
    assert_kind(tampered(_heartbeat(), extra=list(range(5000))), "oversized")
    assert_kind(b"\xdd\xff\xff\xff\xff", "oversized")  # array32 of 2**32 - 1 elements
    assert_kind(b"\xdf\xff\xff\xff\xff", "oversized")  # map32 of 2**32 - 1 entries


# --------------------------------------------------------------------------------------------
# Each error kind, on purpose
# --------------------------------------------------------------------------------------------


def test_truncated_at_many_points(example_message: m.Message) -> None:
    wire = example_message.to_wire()
    cuts = {0, 1, 2, 3, 10, len(wire) // 3, len(wire) // 2, len(wire) - 9, len(wire) - 1}
    for cut in sorted(c for c in cuts if 0 <= c < len(wire)):
        assert kind_of(wire[:cut]) == "truncated", cut


@pytest.mark.parametrize(
    "payload",
    [
        b"",  # no dtype byte
        b"d",  # no dimension count
        b"d\x02\x03\x00\x00\x00",  # second dimension missing
        b"d\x01\x03\x00\x00\x00" + bytes(16),  # 3 float64 need 24 bytes
    ],
    ids=["no-dtype", "no-ndim", "short-shape", "short-data"],
)
def test_truncated_array_payload(payload: bytes) -> None:
    assert_kind(tampered(_vehicle_state(), intent_xy=msgpack.ExtType(1, payload)), "truncated")


MALFORMED: dict[str, Callable[[], bytes]] = {
    "not a map": lambda: pack([1, 2, 3]),
    "a bare integer": lambda: pack(7),
    "missing type": lambda: tampered(_heartbeat(), type=DELETE),
    "type not a string": lambda: tampered(_heartbeat(), type=1),
    "missing header": lambda: tampered(_heartbeat(), header=DELETE),
    "header not a map": lambda: tampered(_heartbeat(), header=[0, 0, "", ""]),
    "header seq a float": lambda: tampered(
        _heartbeat(), header={"stamp_ns": 1, "seq": 1.0, "frame_id": "", "source": ""}
    ),
    "header source missing": lambda: tampered(
        _heartbeat(), header={"stamp_ns": 1, "seq": 1, "frame_id": ""}
    ),
    "string where a float is wanted": lambda: tampered(_vehicle_state(), x_m="12.5"),
    "nil where a float is wanted": lambda: tampered(_vehicle_state(), x_m=None),
    "float where an int is wanted": lambda: tampered(_raw_scan(), sweep_index=3.0),
    "bool where an int is wanted": lambda: tampered(_raw_scan(), sweep_index=True),
    "bool where a float is wanted": lambda: tampered(_vehicle_state(), x_m=True),
    "int where a bool is wanted": lambda: tampered(_environment(), sensor_ok=1),
    "int where a string is wanted": lambda: tampered(_head_state(), mode=1),
    "list where an array is wanted": lambda: tampered(_vehicle_state(), intent_xy=[[1.0, 2.0]]),
    "wrong array dtype": lambda: tampered(
        _vehicle_state(), pose_covariance=typed_array(np.eye(3), "f4")
    ),
    "int array where float wanted": lambda: tampered(
        _environment(), obstacle_id=typed_array([3.0, 7.0, 12.0])
    ),
    "wrong fixed size": lambda: tampered(_vehicle_state(), pose_covariance=typed_array(np.eye(2))),
    "wrong dimension count": lambda: tampered(
        _features(), covariance=typed_array(np.zeros((3, 4, 4, 1)))
    ),
    "mismatched n": lambda: tampered(_raw_scan(), pan_rad=typed_array(np.zeros(N_SAMPLES - 1))),
    "mismatched k": lambda: tampered(_environment(), extent=typed_array(np.zeros((4, 4)))),
    "counters not a map": lambda: tampered(_heartbeat(), counters=[1, 2]),
    "bool counter": lambda: tampered(_heartbeat(), counters={"received": True}),
    "trailing bytes": lambda: _heartbeat().to_wire() + b"\xc0",
    "two messages": lambda: _heartbeat().to_wire() * 2,
    "unknown ext code": lambda: tampered(_vehicle_state(), intent_xy=msgpack.ExtType(2, b"d\x00")),
    "unknown dtype code": lambda: tampered(
        _vehicle_state(), pose_covariance=typed_array(np.eye(3), code=b"e")
    ),
    "array data too long": lambda: tampered(
        _vehicle_state(), intent_xy=raw_ext(b"d", (1, 2), bytes(24))
    ),
    "invalid utf-8": lambda: b"\x81\xa4type\xa2\xff\xfe",
    "integer map key": lambda: b"\x81\x01\x01",
    "never-used byte 0xc1": lambda: b"\xc1",
}


@pytest.mark.parametrize("case", list(MALFORMED))
def test_malformed(case: str) -> None:
    assert_kind(MALFORMED[case](), "malformed")


def test_unknown_type() -> None:
    assert_kind(tampered(_heartbeat(), type="nope/1"), "unknown_type", "nope/1")
    assert_kind(tampered(_heartbeat(), type=""), "unknown_type")
    assert_kind(tampered(_heartbeat(), type="heartbeats/1"), "unknown_type")


def test_wrong_version() -> None:
    assert_kind(tampered(_raw_scan(), type="raw_scan/2"), "wrong_version", "raw_scan/1")
    assert_kind(tampered(_raw_scan(), type="raw_scan/0"), "wrong_version")
    assert_kind(tampered(_raw_scan(), type="raw_scan"), "wrong_version")
    with pytest.raises(MessageError) as info:  # the version is checked before the expectation
        m.decode(tampered(_raw_scan(), type="raw_scan/2"), expect=m.VehicleState)
    assert info.value.kind == "wrong_version"


OUT_OF_RANGE: dict[str, Callable[[], bytes]] = {
    "NaN float": lambda: tampered(_vehicle_state(), x_m=NAN),
    "infinite float": lambda: tampered(_vehicle_state(), y_m=math.inf),
    "float above its bound": lambda: tampered(_vehicle_state(), speed_m_s=5.5),
    "float below its bound": lambda: tampered(_environment(), valid_for_s=-0.1),
    "int above its bound": lambda: tampered(_raw_scan(), direction=2),
    "int below its bound": lambda: tampered(_head_state(), command_seq=-2),
    "negative pid": lambda: tampered(_heartbeat(), pid=-1),
    "negative counter": lambda: tampered(_heartbeat(), counters={"received": -1}),
    "negative header seq": lambda: tampered(
        _heartbeat(), header={"stamp_ns": 1, "seq": -1, "frame_id": "", "source": "x"}
    ),
    "negative header stamp": lambda: tampered(
        _heartbeat(), header={"stamp_ns": -1, "seq": 0, "frame_id": "", "source": "x"}
    ),
    "mode not in its choices": lambda: tampered(_head_state(), mode="flying"),
    "state not in its choices": lambda: tampered(_heartbeat(), state="Running"),
    "NaN in an array that forbids it": lambda: tampered(
        _raw_scan(), time_s=typed_array(np.where(np.arange(N_SAMPLES) == 7, NAN, 1.0))
    ),
    "inf in an array that allows NaN": lambda: tampered(
        _calibrated_scan(), range_m=typed_array(np.full(N_SAMPLES, math.inf))
    ),
    "inf among NaN in an array that allows NaN": lambda: tampered(
        _calibrated_scan(),
        sigma_m=typed_array(np.where(np.arange(N_SAMPLES) == 3, math.inf, NAN)),
    ),
    "-inf in an array that forbids NaN": lambda: tampered(
        _raw_scan(), time_s=typed_array(np.where(np.arange(N_SAMPLES) == 9, -math.inf, 1.0))
    ),
    "array value below its bound": lambda: tampered(
        _raw_scan(), mirror_angle_rad=typed_array(np.full(N_SAMPLES, -2.0))
    ),
    "array value above its bound": lambda: tampered(
        _raw_scan(), mirror_angle_rad=typed_array(np.full(N_SAMPLES, 2.0))
    ),
    "negative value in a non-negative array": lambda: tampered(
        _features(), reflectivity=typed_array([1.0, -0.5, NAN])
    ),
    "uint8 kind above its bound": lambda: tampered(
        _features(), kind=typed_array(np.array([0, 1, 5], dtype=np.uint8), "u1")
    ),
    "negative track id": lambda: tampered(
        _tracks(), track_id=typed_array(np.array([3, -7, 12], dtype=np.int64), "i8")
    ),
}


@pytest.mark.parametrize("case", list(OUT_OF_RANGE))
def test_out_of_range(case: str) -> None:
    assert_kind(OUT_OF_RANGE[case](), "out_of_range")


def test_boundary_values_are_in_range() -> None:
    """Bounds are inclusive."""
    assert kind_of(tampered(_raw_scan(), direction=-1)) == "ok"
    assert kind_of(tampered(_vehicle_state(), speed_m_s=5.0)) == "ok"
    assert kind_of(tampered(_vehicle_state(), speed_m_s=-5)) == "ok"  # an int for a float
    assert kind_of(tampered(_head_state(), command_seq=-1)) == "ok"
    assert kind_of(tampered(_environment(), valid_for_s=60.0)) == "ok"
    top = typed_array(np.full(N_SAMPLES, m.PI / 2))
    assert kind_of(tampered(_raw_scan(), mirror_angle_rad=top)) == "ok"
    no_readings = typed_array(np.full(N_SAMPLES, NAN))  # NaN everywhere: nothing to range-check
    assert kind_of(tampered(_calibrated_scan(), range_m=no_readings)) == "ok"


def test_unknown_fields_are_ignored() -> None:
    """Forward compatibility: a newer writer's extra fields do not disturb an older reader."""
    data = tampered(
        _environment(),
        zz_new_scalar=1.5,
        zz_new_map={"a": [1, 2, {"b": None}]},
        zz_new_array=typed_array(np.zeros((2, 7))),
        zz_new_bytes=b"\x00\xff",
    )
    assert_messages_equal(m.decode(data), _environment())
    header = {"stamp_ns": 5, "seq": 6, "frame_id": "odom", "source": "c", "zz_new": 1}
    decoded = m.decode(tampered(_vehicle_state(), header=header))
    assert decoded.header == m.Header(stamp_ns=5, seq=6, frame_id="odom", source="c")


OPTIONAL_DEFAULTS = [
    (_environment, "valid_for_s", 0.3),
    (_head_command, "laser", True),
    (_head_state, "command_accepted", True),
    (_head_state, "command_message", ""),
    (_calibrated_scan, "scan_angle_sigma_rad", 1e-4),
    (_world_truth, "world_name", ""),
    (_stop, "reason", ""),
    (_stop, "process", ""),
    (_heartbeat, "counters", {}),
]


@pytest.mark.parametrize(("make", "name", "default"), OPTIONAL_DEFAULTS)
def test_missing_optional_field_takes_its_default(
    make: Callable[[], m.Message], name: str, default: Any
) -> None:
    msg = make()
    decoded = m.decode(tampered(msg, **{name: DELETE}))
    assert getattr(decoded, name) == default
    assert_messages_equal(decoded, dataclasses.replace(msg, **{name: default}))  # type: ignore[type-var]


def test_missing_optional_arrays_read_as_not_given() -> None:
    """An older agent's vector (no far profile, no scan window or its darkness, nothing said
    maintained, no end hits, no seen profiles, no across-line σ, no ages) reads with all of
    them empty."""
    msg = _environment()
    decoded = m.decode(
        tampered(
            msg, free_far_m=DELETE, scan_window_rad=DELETE, maintained=DELETE,
            free_end_hit=DELETE, scan_dark_m=DELETE, seen_range_m=DELETE, seen_far_m=DELETE,
            seen_end_hit=DELETE, across_sigma_m=DELETE, seen_age_s=DELETE,
        )
    )  # fmt: skip
    assert isinstance(decoded, m.EnvironmentVector)
    for name in ("free_far_m", "scan_window_rad", "scan_dark_m", "seen_range_m", "seen_far_m",
                 "across_sigma_m", "seen_age_s"):  # fmt: skip
        value = getattr(decoded, name)
        assert value.shape == (0,) and value.dtype == np.float64, name
    for name in ("maintained", "free_end_hit", "seen_end_hit"):
        value = getattr(decoded, name)
        assert value.shape == (0,) and value.dtype == np.uint8, name
    empty, none = np.zeros(0), np.zeros(0, np.uint8)
    assert_messages_equal(
        decoded,
        dataclasses.replace(
            msg,
            free_far_m=empty,
            scan_window_rad=empty,
            maintained=none,
            free_end_hit=none,
            scan_dark_m=empty,
            seen_range_m=empty,
            seen_far_m=empty,
            seen_end_hit=none,
            across_sigma_m=empty,
            seen_age_s=empty,
        ),
    )


def test_tracks_of_an_older_tracker_read_with_no_information_bits() -> None:
    msg = _tracks()
    decoded = m.decode(tampered(msg, information_bits=DELETE))
    assert isinstance(decoded, m.Tracks)
    assert decoded.information_bits.shape == (0,)
    assert_messages_equal(decoded, dataclasses.replace(msg, information_bits=np.zeros(0)))


def test_missing_required_field_is_malformed(example_message: m.Message) -> None:
    cls = type(example_message)
    required = [
        f.name
        for f in dataclasses.fields(cls)  # type: ignore[arg-type]
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    assert "header" in required
    for name in required:
        assert_kind(tampered(example_message, **{name: DELETE}), "malformed", name)


# --------------------------------------------------------------------------------------------
# Fuzzing
# --------------------------------------------------------------------------------------------

FUZZ_RANDOM = 5_000
FUZZ_MUTATIONS = 20_000
FUZZ_SEED = 20260101


def _ext_payloads(wire: bytes, msg: m.Message) -> list[tuple[int, int]]:
    """(offset of the payload, ndim) of every typed array in a message's bytes."""
    found = set()
    for f in dataclasses.fields(msg):  # type: ignore[arg-type]
        if f.name == "header" or f.metadata["spec"].kind != "array":
            continue
        value = getattr(msg, f.name)
        ext = typed_array(value, f.metadata["spec"].dtype)
        packed = pack(ext)
        start = wire.find(packed)
        while start >= 0:
            found.add((start + len(packed) - len(ext.data), value.ndim))
            start = wire.find(packed, start + 1)
    return sorted(found)


def _mutate(
    rng: np.random.Generator, wire: bytes, other: bytes, exts: list[tuple[int, int]]
) -> bytes:
    """One random mutation of a valid message (``other``: a second one, for splicing)."""
    data = bytearray(wire)
    n = len(data)
    how = int(rng.integers(9 if exts else 7))
    if how == 0:  # flip bits in a few bytes anywhere
        for at in rng.integers(n, size=int(rng.integers(1, 5))):
            data[at] ^= int(rng.integers(1, 256))
    elif how == 1:  # flip a byte near the start: map header, type tag, header map
        data[int(rng.integers(min(n, 48)))] ^= int(rng.integers(1, 256))
    elif how == 2:  # overwrite a byte with a random value
        data[int(rng.integers(n))] = int(rng.integers(256))
    elif how == 3:  # truncate
        del data[int(rng.integers(n)) :]
    elif how == 4:  # insert random bytes
        at = int(rng.integers(n + 1))
        data[at:at] = rng.integers(256, size=int(rng.integers(1, 9)), dtype=np.uint8).tobytes()
    elif how == 5:  # delete a slice
        at = int(rng.integers(n))
        del data[at : at + int(rng.integers(1, 17))]
    elif how == 6:  # splice: the start of one message, the end of another
        data = data[: int(rng.integers(n + 1))] + other[int(rng.integers(len(other) + 1)) :]
    else:  # rewrite a typed array's header: dtype code, ndim or one dimension
        start, ndim = exts[int(rng.integers(len(exts)))]
        part = int(rng.integers(3))
        if part == 0:
            data[start] = b"dfqiB?e\x00"[int(rng.integers(8))]
        elif part == 1:
            data[start + 1] = int(rng.choice([0, 1, 2, 3, 4, 5, 9, 255]))
        elif ndim > 0:
            at = start + 2 + 4 * int(rng.integers(ndim))
            (old,) = struct.unpack_from("<I", data, at)
            choices = [0, 1, old - 1, old + 1, 2 * old, 1 << 20, (1 << 20) + 1, 0xFFFFFFFF]
            new = choices[int(rng.integers(len(choices)))] % (1 << 32)
            struct.pack_into("<I", data, at, new)
    return bytes(data)


def _fuzz_inputs(rng: np.random.Generator) -> list[bytes]:
    inputs = [
        rng.integers(256, size=int(rng.integers(0, 2001)), dtype=np.uint8).tobytes()
        for _ in range(FUZZ_RANDOM)
    ]
    messages = [example(tag) for tag in TAGS]
    wires = [msg.to_wire() for msg in messages]
    exts = [_ext_payloads(wire, msg) for wire, msg in zip(wires, messages, strict=True)]
    for i in range(FUZZ_MUTATIONS):
        j = i % len(wires)
        other = wires[int(rng.integers(len(wires)))]
        inputs.append(_mutate(rng, wires[j], other, exts[j]))
    return inputs


def test_fuzz_decode_raises_only_message_error() -> None:
    """Random bytes and mutated messages: decode either succeeds or raises MessageError."""
    started = time.perf_counter()
    rng = np.random.default_rng(FUZZ_SEED)
    inputs = _fuzz_inputs(rng)
    kinds: Counter[str] = Counter()
    failures: list[str] = []
    for data in inputs:
        try:
            decoded = m.decode(data)
            m.peek_type(data)
        except MessageError as exc:
            kinds[exc.kind] += 1
            continue
        except Exception as exc:
            failures.append(f"{type(exc).__name__}: {exc} on input {data.hex()}")
            continue
        kinds["ok"] += 1
        try:  # whatever is accepted can be sent on, and reads back the same
            assert_messages_equal(m.decode(decoded.to_wire()), decoded)
        except Exception as exc:
            failures.append(f"re-encoding: {type(exc).__name__}: {exc} on input {data.hex()}")
    elapsed = time.perf_counter() - started
    assert not failures, f"{len(failures)} inputs raised other errors; first: {failures[0]}"
    assert len(inputs) >= 10_000
    seen = set(kinds) - {"ok"}
    assert len(seen) >= len(KINDS) - 1, f"kinds seen: {dict(kinds)}"
    assert {"malformed", "truncated", "oversized", "out_of_range"} <= seen, dict(kinds)
    assert kinds["ok"] > 0, dict(kinds)  # some mutations only touch values
    print(f"fuzz: {len(inputs)} inputs in {elapsed:.2f} s: {dict(sorted(kinds.items()))}")


def test_fuzz_inputs_are_deterministic() -> None:
    a = _fuzz_inputs(np.random.default_rng(FUZZ_SEED))[::997]
    b = _fuzz_inputs(np.random.default_rng(FUZZ_SEED))[::997]
    assert a == b


# --------------------------------------------------------------------------------------------
# Topics
# --------------------------------------------------------------------------------------------


def test_every_message_type_has_exactly_one_topic() -> None:
    carried = Counter(topics.TOPIC_TYPES.values())
    for cls in m.REGISTRY.values():
        assert carried[cls] == 1, f"{cls.__name__} is carried by {carried[cls]} topics"
    assert set(carried) <= set(m.REGISTRY.values())
    for topic, cls in topics.TOPIC_TYPES.items():
        assert topics.message_type(topic) is cls
    assert topics.LATCHED.issubset(topics.TOPIC_TYPES)


def test_unknown_topic_is_a_key_error_naming_it() -> None:
    with pytest.raises(KeyError, match="nope"):
        topics.message_type("nope")


# --------------------------------------------------------------------------------------------
# docs/interface.md stays true
# --------------------------------------------------------------------------------------------


def _doc() -> str:
    return INTERFACE_DOC.read_text(encoding="utf-8")


def _doc_python_example() -> dict[str, Any]:
    """Run the doc's ```python block as a module that is not __main__ (no sockets opened)."""
    blocks = re.findall(r"^```python\n(.*?)^```$", _doc(), flags=re.MULTILINE | re.DOTALL)
    assert len(blocks) == 1, "docs/interface.md must hold exactly one ```python block"
    namespace: dict[str, Any] = {"__name__": "interface_doc_example"}
    exec(compile(blocks[0], str(INTERFACE_DOC), "exec"), namespace)
    return namespace


def test_doc_example_encodes_a_vehicle_state_the_agent_accepts() -> None:
    example_ns = _doc_python_example()
    want = _vehicle_state()
    data = example_ns["encode_vehicle_state"](
        seq=want.header.seq,
        stamp_ns=want.header.stamp_ns,
        x_m=want.x_m,
        y_m=want.y_m,
        yaw_rad=want.yaw_rad,
        speed_m_s=want.speed_m_s,
        yaw_rate_rad_s=want.yaw_rate_rad_s,
        pose_covariance=want.pose_covariance.ravel().tolist(),
        intent_xy=[tuple(p) for p in want.intent_xy.tolist()],
        watch_xy=[tuple(p) for p in want.watch_xy.tolist()],
    )
    got = m.decode(data, expect=m.VehicleState)
    assert_messages_equal(got, want.with_header(source=got.header.source))
    assert got.header.frame_id == "odom"
    # an empty intent (no waypoints) is a (0, 2) array
    empty = example_ns["encode_vehicle_state"](0, 1, 0, 0, 0, 0, 0, [0.0] * 9, [])
    decoded = m.decode(empty, expect=m.VehicleState)
    assert isinstance(decoded, m.VehicleState)
    assert decoded.intent_xy.shape == (0, 2)
    assert decoded.watch_xy.shape == (0, 2)


def test_doc_example_decodes_environment_vectors() -> None:
    example_ns = _doc_python_example()
    env = _environment()
    msg = example_ns["decode_message"](env.to_wire())
    assert msg["type"] == "environment/1"
    assert msg["sensor_ok"] is True
    assert msg["valid_for_s"] == env.valid_for_s
    assert msg["header"]["stamp_ns"] == env.header.stamp_ns
    for name in array_fields(m.EnvironmentVector):
        shape, values = msg[name]
        want = getattr(env, name)
        assert tuple(shape) == want.shape, name
        np.testing.assert_array_equal(np.array(values).reshape(shape), want, err_msg=name)
    assert example_ns["usable"](msg, env.header.stamp_ns + 10**8)
    assert not example_ns["usable"](msg, env.header.stamp_ns + 4 * 10**8)  # stale
    assert not example_ns["usable"](dict(msg, sensor_ok=False), env.header.stamp_ns)
    assert not example_ns["usable"](None, env.header.stamp_ns)


def test_doc_worked_array_example_is_the_encoders_output() -> None:
    packed = pack(m._pack_array(np.array([1.0, 2.0]), "f8"))
    assert packed.hex(" ") in _doc()
    assert packed == pack(typed_array([1.0, 2.0]))


def _number(x: float) -> str:
    """A bound as the doc writes it: int64's limits as powers of 2, multiples of π/2 in π,
    others in %g."""
    if x == m.INT64_MAX:
        return "2⁶³−1"
    if x == m.INT64_MIN:
        return "−2⁶³"
    halves = x / (m.PI / 2)
    if x != 0 and abs(halves - round(halves)) < 1e-12:
        k = round(halves)
        sign = "−" if k < 0 else ""
        k = abs(k)
        return f"{sign}π/2" if k == 1 else f"{sign}{k // 2 if k != 2 else ''}π"
    return f"{x:g}".replace("-", "−")


def _range_text(spec: m.Spec) -> str:
    parts = []
    if spec.kind in ("float", "array") and spec.dtype in ("", "f8", "f4"):
        if spec.kind == "float" or not spec.allow_nan:
            parts.append("finite")
        else:
            parts.append("finite or NaN")
    if spec.kind == "dict":  # the bounds are its values'
        assert spec.lo is not None and spec.hi is not None
        parts.append(f"values {_number(spec.lo)} … {_number(spec.hi)}")
    elif spec.lo is not None and spec.hi is not None:
        parts.append(f"{_number(spec.lo)} … {_number(spec.hi)}")
    elif spec.lo is not None:
        parts.append(f"≥ {_number(spec.lo)}")
    elif spec.hi is not None:
        parts.append(f"≤ {_number(spec.hi)}")
    if spec.choices:
        parts.append(", ".join(f'`"{c}"`' for c in spec.choices))
    elif spec.kind == "str":
        parts.append(f"≤ {m.MAX_STRING_CHARS} characters")
    return "; ".join(parts) or "—"


_DTYPE_NAMES = {"f8": "float64", "f4": "float32", "i8": "int64", "i4": "int32", "u1": "uint8"}


def _type_text(spec: m.Spec) -> str:
    if spec.kind == "array":
        dims = ", ".join(str(d) for d in spec.dims) + ("," if len(spec.dims) == 1 else "")
        return f"array `{_WIRE_CODES[spec.dtype].decode()}` {_DTYPE_NAMES[spec.dtype]} ({dims})"
    return {
        "float": "float",
        "int": "int",
        "bool": "bool",
        "str": "str",
        "dict": "map str → int",
    }[spec.kind]


def _default_text(f: dataclasses.Field[Any]) -> str:
    if f.default is not dataclasses.MISSING:
        value = f.default
    elif f.default_factory is not dataclasses.MISSING:
        value = f.default_factory()
    else:
        return "required"
    if isinstance(value, bool):
        return "`true`" if value else "`false`"
    if isinstance(value, str):
        return f'`"{value}"`'
    if isinstance(value, dict):
        return "`{}`"
    if isinstance(value, np.ndarray):  # an optional array: empty unless given
        return "empty"
    return f"`{value:g}`"


def field_rows(cls: type[m.Message]) -> list[str]:
    """The first five columns of the doc's field table of a message type, from its specs."""
    rows = []
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if f.name == "header":
            continue
        spec = f.metadata["spec"]
        unit = spec.unit or "—"
        cells = [f"`{f.name}`", _type_text(spec), unit, _range_text(spec), _default_text(f)]
        rows.append("| " + " | ".join(cells) + " |")
    return rows


@pytest.mark.parametrize(
    "cls", [m.VehicleState, m.EnvironmentVector, m.Heartbeat, m.Stop], ids=lambda c: c.TYPE
)
def test_doc_field_tables_match_the_specs(cls: type[m.Message]) -> None:
    doc = _doc()
    for row in field_rows(cls):
        assert row in doc, f"docs/interface.md: {cls.TYPE} row out of date; expected {row}"


def test_doc_whole_message_dump_is_the_golden_stop_message() -> None:
    doc = _doc()
    section = doc[doc.index("### Worked example: a whole message") :]
    block = re.search(r"```text\n(.*?)```", section, flags=re.DOTALL)
    assert block is not None
    dumped = bytearray()
    for line in block.group(1).splitlines():
        for token in line.split():
            if not re.fullmatch(r"[0-9a-f]{2}", token):
                break
            dumped.append(int(token, 16))
    assert bytes(dumped) == golden_path("stop/1").read_bytes()


def test_memoryviews_are_measured_in_bytes() -> None:
    wire = _heartbeat().to_wire()
    assert isinstance(m.decode(memoryview(wire)), m.Heartbeat)
    padding = bytes(8 + (-len(wire) % 8))
    wide = memoryview(np.frombuffer(wire + padding, dtype="<f8"))  # 8-byte items
    error = assert_kind(wide, "malformed")  # type: ignore[arg-type]
    assert f"{len(padding)} bytes after the message" in str(error)  # bytes, not items
    big = memoryview(np.zeros(m.MAX_MESSAGE_BYTES // 8 + 8))
    assert_kind(big, "oversized")  # type: ignore[arg-type]


def test_names_in_header_and_counters_are_limited() -> None:
    long_name = "s" * (m.MAX_NAME_CHARS + 1)
    assert_kind(_heartbeat().with_header(source=long_name).to_wire(), "oversized")
    assert_kind(_heartbeat().with_header(frame_id=long_name).to_wire(), "oversized")
    assert_kind(tampered(_heartbeat(), counters={long_name: 1}), "oversized")
    assert kind_of(_heartbeat().with_header(source="s" * m.MAX_NAME_CHARS).to_wire()) == "ok"


def test_to_wire_replaces_header_fields_without_touching_the_message() -> None:
    msg = m.WheelCommand(
        header=m.Header(stamp_ns=5, seq=1, frame_id="base_link", source="a"),
        speed_m_s=0.1,
        yaw_rate_rad_s=0.0,
    )
    back = m.decode(msg.to_wire(seq=7, source="b", stamp_ns=9))
    assert back.header == m.Header(stamp_ns=9, seq=7, frame_id="base_link", source="b")
    assert msg.header.seq == 1 and msg.header.source == "a"  # unchanged
    assert msg.to_wire(seq=1) == msg.to_wire()  # what is not replaced stays
