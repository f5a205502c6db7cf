"""Tests of agent.runtime.messages.codec, the fast codec, against the reference decoder.

:func:`codec.decode` accepts a message outright or hands it to
:func:`agent.runtime.messages.checks.decode`; whatever it accepts, the reference must accept
with the same values, and every error comes from the reference. Fuzzing at the level of
values (fields set at and beyond their bounds, NaN and inf placed in arrays, array headers
rewritten) compares the two on inputs that reach each check of the fast path. Also: which
messages take the fast path, what decoded arrays are (aligned, read-only, never the
sender's memory), and encoding's conversions and header stamping.
"""

from __future__ import annotations

import dataclasses
import math
import struct
from collections import Counter
from typing import Any

import msgpack
import numpy as np
import numpy.typing as npt
import pytest

from agent.errors import MessageError
from agent.runtime import messages as m
from agent.runtime.messages import checks, codec, reading
from tests.unit.runtime.test_messages import (
    N_SAMPLES,
    NAN,
    TAGS,
    _calibrated_scan,
    _environment,
    _features,
    _filtered_scan,
    _heartbeat,
    _raw_scan,
    _vehicle_state,
    assert_kind,
    assert_messages_equal,
    example,
    kind_of,
    pack,
    tampered,
    to_map,
    typed_array,
)

pytestmark = pytest.mark.filterwarnings("error")

VALUE_FUZZ_INPUTS = 6_000
VALUE_FUZZ_SEED = 20260102


@pytest.fixture
def reference_calls(monkeypatch: pytest.MonkeyPatch) -> list[bytes]:
    """The inputs that codec.decode hands to the reference decoder, as they come."""
    calls: list[bytes] = []
    reference = checks.decode

    def counted(data: bytes, expect: Any = None) -> Any:
        calls.append(data)
        return reference(data, expect)

    monkeypatch.setattr(checks, "decode", counted)
    return calls


def outcome(decode: Any, data: bytes) -> tuple[str, Any]:
    """("ok", message) or (error kind, error text)."""
    try:
        return "ok", decode(data)
    except MessageError as exc:
        return exc.kind, str(exc)


# --------------------------------------------------------------------------------------------
# Which messages take the fast path
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("tag", TAGS)
def test_every_example_takes_the_fast_path(tag: str, reference_calls: list[bytes]) -> None:
    msg = example(tag)
    wire = msg.to_wire()
    assert_messages_equal(m.decode(wire), msg)
    assert_messages_equal(m.decode(wire, expect=type(msg)), msg)
    assert reference_calls == []


def test_empty_arrays_and_all_nan_arrays_take_the_fast_path(reference_calls: list[bytes]) -> None:
    none_found = dataclasses.replace(
        _features(),
        kind=np.zeros(0, np.uint8),
        params=np.zeros((0, 3)),
        covariance=np.zeros((0, 3, 3)),
        endpoints=np.zeros((0, 2, 2)),
        nearer_side=np.zeros(0, np.int32),
        reflectivity=np.zeros(0),
    )
    no_intent = dataclasses.replace(_vehicle_state(), intent_xy=np.zeros((0, 2)))
    no_readings = dataclasses.replace(
        _calibrated_scan(),
        range_m=np.full(N_SAMPLES, NAN),
        sigma_m=np.full(N_SAMPLES, NAN),
        image_position_norm=np.full(N_SAMPLES, NAN),
    )
    for msg in (none_found, no_intent, no_readings):
        assert_messages_equal(m.decode(msg.to_wire()), msg)
    assert reference_calls == []


def test_other_valid_forms_are_decoded_by_the_reference(reference_calls: list[bytes]) -> None:
    """Unknown fields, a map 32 and an array framed longer than needed are valid but rare."""
    env = _environment()
    obj = to_map(env)
    entries = b"".join(pack(k) + pack(v) for k, v in obj.items())
    as_map16 = b"\xde" + struct.pack(">H", len(obj)) + entries
    assert_messages_equal(m.decode(as_map16), env)
    assert reference_calls == []  # a map 16 within the limit is read at once
    with_new_field = tampered(env, zz_new=1.5)
    as_map32 = b"\xdf" + struct.pack(">I", len(obj)) + entries
    kind = obj["kind"]
    ext32 = b"\xc9" + struct.pack(">I", len(kind.data)) + b"\x01" + kind.data
    long_framing = (
        b"\xde"
        + struct.pack(">H", len(obj))
        + b"".join(pack(k) + (ext32 if k == "kind" else pack(v)) for k, v in obj.items())
    )
    for data in (with_new_field, as_map32, long_framing):
        assert_messages_equal(m.decode(data), env)
    assert reference_calls == [with_new_field, as_map32, long_framing]


def test_another_type_than_expected_is_refused_by_the_reference() -> None:
    with pytest.raises(MessageError) as info:
        m.decode(_raw_scan().to_wire(), expect=m.CalibratedScan)
    assert info.value.kind == "unknown_type"


def test_a_type_registered_later_is_decoded(monkeypatch: pytest.MonkeyPatch) -> None:
    @dataclasses.dataclass(frozen=True, eq=False, kw_only=True)
    class Ping(m.Message):
        header: m.Header
        count: int = m.i64(lo=0)

    Ping.TYPE, Ping.VERSION = "ping", 1
    monkeypatch.setattr(codec, "_fast", None)  # whatever earlier tests registered
    _ = m.decode(_heartbeat().to_wire())  # the decoder as it was before
    monkeypatch.setitem(m.REGISTRY, "ping/1", Ping)
    ping = Ping(header=m.Header(seq=3), count=2)
    decoded = m.decode(ping.to_wire())
    assert isinstance(decoded, Ping) and decoded.count == 2 and decoded.header.seq == 3
    assert_kind(tampered(ping, count=-1), "out_of_range")


def test_a_type_no_longer_registered_is_not_decoded(monkeypatch: pytest.MonkeyPatch) -> None:
    @dataclasses.dataclass(frozen=True, eq=False, kw_only=True)
    class Old(m.Message):
        header: m.Header

    @dataclasses.dataclass(frozen=True, eq=False, kw_only=True)
    class New(m.Message):
        header: m.Header

    Old.TYPE, Old.VERSION, New.TYPE, New.VERSION = "old", 1, "new", 1
    monkeypatch.setitem(m.REGISTRY, "old/1", Old)
    old = Old(header=m.Header()).to_wire()
    assert isinstance(m.decode(old), Old)
    del m.REGISTRY["old/1"]
    monkeypatch.setitem(m.REGISTRY, "new/1", New)  # as many types as when Old was known
    assert_kind(old, "unknown_type")
    assert isinstance(m.decode(New(header=m.Header()).to_wire()), New)


def test_a_type_with_post_init_is_made_through_its_init(
    monkeypatch: pytest.MonkeyPatch, reference_calls: list[bytes]
) -> None:
    made: list[int] = []

    @dataclasses.dataclass(frozen=True, eq=False, kw_only=True)
    class Counted(m.Message):
        header: m.Header
        values: npt.NDArray[np.float64] = m.array("f8", ("n",))  # noqa: RUF009  # a field spec

        def __post_init__(self) -> None:
            made.append(self.values.size)

    Counted.TYPE, Counted.VERSION = "counted", 1
    monkeypatch.setitem(m.REGISTRY, "counted/1", Counted)
    monkeypatch.setattr(codec, "_fast", None)  # made again, whatever earlier tests registered
    decoded = m.decode(Counted(header=m.Header(), values=np.arange(4.0)).to_wire())
    assert isinstance(decoded, Counted) and made == [4, 4]
    assert reference_calls == []


def test_a_type_of_many_fields_is_a_map_16_both_ways(
    monkeypatch: pytest.MonkeyPatch, reference_calls: list[bytes]
) -> None:
    names = [f"f{i:02d}_m" for i in range(15)]
    fields = [("header", m.Header)] + [(name, float, m.f64("m")) for name in names]
    Wide = dataclasses.make_dataclass(
        "Wide", fields, bases=(m.Message,), frozen=True, eq=False, kw_only=True
    )
    Wide.TYPE, Wide.VERSION = "wide", 1
    monkeypatch.setitem(m.REGISTRY, "wide/1", Wide)
    monkeypatch.setattr(codec, "_fast", None)  # made again, whatever earlier tests registered
    wide = Wide(header=m.Header(seq=1), **{name: i / 4 for i, name in enumerate(names)})
    wire = wide.to_wire()
    want = {"type": "wide/1", "header": {"stamp_ns": 0, "seq": 1, "frame_id": "", "source": ""}}
    assert wire == pack(want | {name: i / 4 for i, name in enumerate(names)})
    assert wire[0] == 0xDE  # 17 entries
    assert_messages_equal(m.decode(wire), wide)
    assert reference_calls == []


# --------------------------------------------------------------------------------------------
# Decoded arrays
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("tag", TAGS)
def test_decoded_arrays_are_aligned_and_cannot_be_made_writeable(tag: str) -> None:
    decoded = m.decode(example(tag).to_wire())
    for f in dataclasses.fields(decoded):  # type: ignore[arg-type]
        value = getattr(decoded, f.name)
        if isinstance(value, np.ndarray):
            assert value.flags.aligned and value.flags.c_contiguous, f.name
            assert not value.flags.writeable, f.name
            with pytest.raises(ValueError, match=r"(?i)writeable"):
                value.flags.writeable = True


@pytest.mark.parametrize("make_buffer", [bytearray, lambda b: memoryview(bytearray(b))])
def test_a_message_never_shares_memory_with_a_mutable_buffer(make_buffer: Any) -> None:
    """Input that is not ``bytes`` is copied first: the sender may reuse its buffer."""
    want = _filtered_scan()
    buffer = make_buffer(want.to_wire())
    decoded = m.decode(buffer)
    buffer[:] = bytes(len(buffer))  # the sender writes its next message
    assert_messages_equal(decoded, want)


# --------------------------------------------------------------------------------------------
# Checks that only the fast path could get wrong
# --------------------------------------------------------------------------------------------


def _map16(entries: list[tuple[Any, Any]]) -> bytes:
    """A msgpack map16 holding ``entries`` as they are, repeated keys included."""
    return (
        b"\xde" + struct.pack(">H", len(entries)) + b"".join(pack(k) + pack(v) for k, v in entries)
    )


def test_maps_beyond_the_limit_are_oversized_even_with_repeated_keys() -> None:
    # msgspec keeps the last of repeated keys; the limit counts the entries on the wire.
    hb = _heartbeat()
    obj = to_map(hb)
    header = list(obj["header"].items())
    repeated = header + [("seq", 41)] * (m.MAX_MAP_ITEMS + 1 - len(header))
    bodies = {k: pack(v) for k, v in obj.items()}
    bodies["header"] = _map16(repeated)
    data = bytes([0x80 | len(obj)]) + b"".join(pack(k) + bodies[k] for k in obj)
    assert_kind(data, "oversized")
    at_limit = header + [("seq", 41)] * (m.MAX_MAP_ITEMS - len(header))
    bodies["header"] = _map16(at_limit)
    data = bytes([0x80 | len(obj)]) + b"".join(pack(k) + bodies[k] for k in obj)
    assert m.decode(data).header == hb.header
    bodies = {k: pack(v) for k, v in obj.items()}
    bodies["counters"] = _map16([("received", 1)] * (m.MAX_MAP_ITEMS + 1))
    data = bytes([0x80 | len(obj)]) + b"".join(pack(k) + bodies[k] for k in obj)
    assert_kind(data, "oversized")
    top = [*obj.items()] + [("pid", hb.pid)] * (m.MAX_MAP_ITEMS + 1 - len(obj))
    assert_kind(_map16(top), "oversized")


def test_a_repeated_type_tag_is_read_as_the_reference_reads_it() -> None:
    obj = to_map(_heartbeat())
    entries = [*obj.items(), ("type", "stop/1")]  # the last "type" wins: stop/1 lacks nothing
    data = bytes([0x80 | len(entries)]) + b"".join(pack(k) + pack(v) for k, v in entries)
    assert outcome(m.decode, data)[0] == outcome(checks.decode, data)[0]


def test_nan_where_forbidden_beside_nan_where_allowed() -> None:
    """A calibrated scan's arrays share one pass: NaN allowed in range_m, not in time_s."""
    scan = _calibrated_scan()
    assert np.isnan(scan.range_m).any()
    time_s = scan.time_s.copy()
    time_s[5] = NAN
    assert_kind(tampered(scan, time_s=typed_array(time_s)), "out_of_range")
    range_m = scan.range_m.copy()
    range_m[np.flatnonzero(np.isfinite(range_m))[0]] = -math.inf
    assert_kind(tampered(scan, range_m=typed_array(range_m)), "out_of_range")
    range_m[np.flatnonzero(np.isfinite(range_m))[0]] = 100.5
    assert_kind(tampered(scan, range_m=typed_array(range_m)), "out_of_range")


def test_arrays_that_all_allow_nan_are_still_bounded() -> None:
    features = _features()
    reflectivity = features.reflectivity.copy()
    reflectivity[0] = math.inf
    assert_kind(tampered(features, reflectivity=typed_array(reflectivity)), "out_of_range")
    params = features.params.copy()
    params[2, 2] = -math.inf
    assert_kind(tampered(features, params=typed_array(params)), "out_of_range")


def test_uint8_bounds_at_the_boundary() -> None:
    scan = _filtered_scan()
    flag = scan.flag.copy()
    flag[-1] = 5
    assert kind_of(tampered(scan, flag=typed_array(flag, "u1"))) == "ok"
    flag[-1] = 6
    assert_kind(tampered(scan, flag=typed_array(flag, "u1")), "out_of_range")
    flag[-1] = 255
    assert_kind(tampered(scan, flag=typed_array(flag, "u1")), "out_of_range")


def test_many_distinct_sizes_decode_and_the_reader_cache_stays_bounded() -> None:
    for n in range(1, 3 * reading._MAX_READERS):
        scan = dataclasses.replace(
            _raw_scan(),
            time_s=np.arange(n, dtype=np.float64),
            mirror_angle_rad=np.zeros(n),
            pan_rad=np.zeros(n),
            current_1_A=np.zeros(n),
            current_2_A=np.zeros(n),
        )
        assert_messages_equal(m.decode(scan.to_wire()), scan)
    reader = next(r for r in codec._fast_decoder()[2].values() if r.cls is m.RawScan)
    assert 0 < len(reader._readers) <= reading._MAX_READERS


# --------------------------------------------------------------------------------------------
# Fuzzing values: the fast path accepts nothing the reference refuses
# --------------------------------------------------------------------------------------------


def _spec(cls: type[m.Message], name: str) -> m.Spec | None:
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if f.name == name:
            spec = f.metadata.get("spec")
            return spec if isinstance(spec, m.Spec) else None
    return None


def _edges(spec: m.Spec | None) -> list[Any]:
    """Values at and just beyond a spec's bounds."""
    out: list[Any] = []
    for bound, away in ((None if spec is None else spec.lo, -math.inf),
                        (None if spec is None else spec.hi, math.inf)):  # fmt: skip
        if bound is not None:
            out += [
                bound,
                float(np.nextafter(bound, away)),
                int(bound),
                int(bound) + (1 if away > 0 else -1),
            ]
    return out


_SCALARS: list[Any] = [
    NAN, math.inf, -math.inf, 0, -1, 1, 0.5, -0.5, 1e300, -1e300, 2**63 - 1, 2**64 - 1, -(2**63),
    True, False, None, "", "running", "slewing", "x" * 4097, b"x", [], {}, [1.0],
]  # fmt: skip


def _array_mutation(rng: np.random.Generator, ext: msgpack.ExtType, spec: m.Spec | None) -> Any:
    data = ext.data
    if len(data) < 2 or data[:1] not in m.arrays.DTYPES or data[1] > m.MAX_DIMENSIONS:
        return ext
    dt = m.arrays.DTYPES[data[:1]]
    ndim = data[1]
    shape = struct.unpack_from(f"<{ndim}I", data, 2)
    values = np.frombuffer(data, dt, offset=2 + 4 * ndim).reshape(shape).copy()
    how = int(rng.integers(6))
    if how <= 2 and values.size:  # a few elements set to edge or special values
        pool: list[Any] = _edges(spec)
        if dt.kind == "f":
            pool += [NAN, math.inf, -math.inf, 0.0, 1e300]
        else:
            info = np.iinfo(dt)
            pool += [info.min, info.max, 0, -1 if info.min < 0 else 0]
        flat = values.reshape(-1)
        for _ in range(int(rng.integers(1, 4))):
            v = pool[int(rng.integers(len(pool)))]
            try:
                flat[int(rng.integers(flat.size))] = v
            except (OverflowError, ValueError):
                continue
        return msgpack.ExtType(1, data[: 2 + 4 * ndim] + values.tobytes())
    if how == 3 and dt.kind == "f":  # every value NaN
        return msgpack.ExtType(1, data[: 2 + 4 * ndim] + np.full(shape, NAN, dt).tobytes())
    if how == 4:  # another dtype code or dimension count
        b = bytearray(data)
        b[int(rng.integers(2))] = int(
            rng.choice([0x64, 0x66, 0x71, 0x69, 0x42, 0x3F, 0, 1, 2, 3, 5])
        )
        return msgpack.ExtType(1, bytes(b))
    if ndim:  # one dimension changed, the data kept or cut to fit
        b = bytearray(data)
        at = 2 + 4 * int(rng.integers(ndim))
        (old,) = struct.unpack_from("<I", b, at)
        struct.pack_into("<I", b, at, int(rng.choice([0, 1, max(0, old - 1), old + 1])))
        return msgpack.ExtType(int(rng.choice([1, 1, 1, 2])), bytes(b))
    return ext


def _value_mutation(rng: np.random.Generator, msg: m.Message) -> bytes:
    obj = to_map(msg)
    names = [k for k in obj if k != "type"] + ["zz_new"]
    name = names[int(rng.integers(len(names)))]
    spec = _spec(type(msg), name)
    value = obj.get(name)
    if name == "header":
        assert isinstance(value, dict)
        header = dict(value)
        key = ["stamp_ns", "seq", "frame_id", "source", "zz"][int(rng.integers(5))]
        pool = [-1, 0, 2**64 - 1, 1.0, True, None, "", "s" * 256, "s" * 257, b"s", [1]]
        choice = pool[int(rng.integers(len(pool)))] if rng.integers(6) else DELETE_KEY
        if choice is DELETE_KEY:
            header.pop(key, None)
        else:
            header[key] = choice
        obj["header"] = header
    elif isinstance(value, msgpack.ExtType):
        obj[name] = _array_mutation(rng, value, spec)
    elif isinstance(value, dict):
        pool_maps: list[Any] = [
            {},
            {"a": -1},
            {"a": True},
            {"a": 1.0},
            {"n" * 257: 1},
            {"n" * 256: 0},
        ]
        obj[name] = pool_maps[int(rng.integers(len(pool_maps)))]
    elif rng.integers(8) == 0:
        obj.pop(name, None)
    else:
        pool = _SCALARS + _edges(spec) + list(spec.choices if spec else ())
        obj[name] = pool[int(rng.integers(len(pool)))]
    packed: bytes = msgpack.packb(obj, use_bin_type=True)
    return packed


DELETE_KEY = object()


def test_fast_and_reference_decoders_agree_on_fuzzed_values(reference_calls: list[bytes]) -> None:
    rng = np.random.default_rng(VALUE_FUZZ_SEED)
    messages = [example(tag) for tag in TAGS]
    kinds: Counter[str] = Counter()
    fast_ok = 0
    for i in range(VALUE_FUZZ_INPUTS):
        data = _value_mutation(rng, messages[i % len(messages)])
        reference_calls.clear()
        fast = outcome(m.decode, data)
        by_fast_path = not reference_calls
        want = outcome(checks.decode, data)
        kinds[fast[0]] += 1
        assert fast[0] == want[0], f"{fast} but the reference says {want}, input {data.hex()}"
        if fast[0] == "ok":
            assert_messages_equal(fast[1], want[1])
            assert fast[1].header == want[1].header
            fast_ok += by_fast_path
        else:
            assert fast[1] == want[1]
    print(f"value fuzz: {dict(sorted(kinds.items()))}, {fast_ok} accepted by the fast path")
    # The fuzzing reaches both sides of the fast path's checks.
    assert fast_ok > VALUE_FUZZ_INPUTS // 10, dict(kinds)
    assert {"malformed", "oversized", "out_of_range", "truncated"} <= set(kinds), dict(kinds)
    assert kinds["out_of_range"] > VALUE_FUZZ_INPUTS // 10, dict(kinds)


# --------------------------------------------------------------------------------------------
# Encoding
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("tag", TAGS)
def test_stamping_on_the_wire_is_stamping_the_message(tag: str) -> None:
    msg = example(tag)
    stamped = msg.to_wire(seq=7, source="publisher", stamp_ns=123)
    assert stamped == msg.with_header(seq=7, source="publisher", stamp_ns=123).to_wire()
    assert stamped == m.encode(msg, seq=7, source="publisher", stamp_ns=123)
    assert msg.to_wire(source="publisher") == msg.with_header(source="publisher").to_wire()


def test_encoding_converts_to_the_declared_types() -> None:
    """numpy scalars, other dtypes, Fortran order and lists encode as the declared values."""
    vs = _vehicle_state()
    loose = dataclasses.replace(
        vs,
        header=m.Header(
            stamp_ns=np.int64(vs.header.stamp_ns),  # type: ignore[arg-type]
            seq=np.uint32(vs.header.seq),  # type: ignore[arg-type]
            frame_id=vs.header.frame_id,
            source=vs.header.source,
        ),
        x_m=np.float64(vs.x_m),
        y_m=np.float32(vs.y_m),  # type: ignore[arg-type]  # -3.25 is exact in float32
        speed_m_s=np.float64(vs.speed_m_s),
        pose_covariance=np.asfortranarray(vs.pose_covariance),
        intent_xy=vs.intent_xy.astype(np.float32).tolist(),
    )
    assert loose.to_wire() == vs.to_wire()
    hb = _heartbeat()
    loose_hb = dataclasses.replace(
        hb,
        pid=np.int64(hb.pid),  # type: ignore[arg-type]
        process=np.str_(hb.process),
        counters={k: np.int64(v) for k, v in hb.counters.items()},  # type: ignore[misc]
    )
    assert loose_hb.to_wire() == hb.to_wire()
    fs = _filtered_scan()
    assert dataclasses.replace(fs, flag=fs.flag.astype(np.int64)).to_wire() == fs.to_wire()


def test_encoding_refuses_what_it_cannot_write() -> None:
    with pytest.raises(TypeError, match="cannot encode"):
        dataclasses.replace(_heartbeat(), process=object()).to_wire()  # type: ignore[arg-type]


def test_unregistered_subclass_encodes_with_its_tag() -> None:
    @dataclasses.dataclass(frozen=True, eq=False, kw_only=True)
    class Local(m.Message):
        header: m.Header
        value_m: float = m.f64("m", 0.0, 1.0)

    Local.TYPE, Local.VERSION = "local", 3
    obj = msgpack.unpackb(Local(header=m.Header(), value_m=0.5).to_wire())
    assert obj["type"] == "local/3" and obj["value_m"] == 0.5
