"""The wire contract's limits on what a message may hold anywhere (docs/interface.md, §2).

* No extension other than a well-formed typed array, in known fields, in fields the reader
  does not know, in the header, inside maps (a heartbeat's counters) and nested arrays.
* Every integer read is an int64 within its field's range: ``stamp_ns``, ``seq``, int
  fields, counter values; a msgpack uint64 above 2⁶³−1 is out of range.
* Maps and arrays nest at most 32 levels; 100 000 levels are refused as ``oversized``, never
  with a RecursionError.

Each hostile input goes to both decoders, the fast one (:func:`agent.runtime.messages.decode`)
and the reference (:func:`agent.runtime.messages.checks.decode`): they must refuse it with
the same kind and the same one-line message, naming where the problem is.
"""

from __future__ import annotations

import dataclasses
import struct
from collections import Counter
from collections.abc import Callable
from typing import Any

import msgpack
import numpy as np
import pytest

from agent.errors import MessageError
from agent.runtime import messages as m
from agent.runtime.messages import checks
from tests.unit.runtime.test_messages import (
    TAGS,
    _filtered_scan,
    _head_state,
    _heartbeat,
    _raw_scan,
    _vehicle_state,
    assert_messages_equal,
    example,
    pack,
    raw_ext,
    tampered,
    to_map,
    typed_array,
)

pytestmark = pytest.mark.filterwarnings("error")

# The limits as docs/interface.md states them.
DEPTH_LIMIT = 32
INT64_MAX = 2**63 - 1
INT64_MIN = -(2**63)
UINT64_MAX = 2**64 - 1

HOSTILE_SEED = 20260317
HOSTILE_INPUTS = 3_000


def outcomes(data: bytes) -> tuple[tuple[str, Any], tuple[str, Any]]:
    """What each decoder makes of ``data``: ("ok", message) or (kind, error text)."""

    def run(decode: Callable[[bytes], m.Message]) -> tuple[str, Any]:
        try:
            return "ok", decode(data)
        except MessageError as exc:
            return exc.kind, str(exc)

    return run(m.decode), run(checks.decode)


def refused(data: bytes, kind: str, *needles: str) -> str:
    """Both decoders refuse ``data`` alike, with ``kind`` and one line holding ``needles``."""
    fast, reference = outcomes(data)
    assert fast == reference, f"fast {fast}, reference {reference}"
    assert fast[0] == kind, fast
    text: str = fast[1]
    assert "\n" not in text and len(text) < 300, text
    for needle in needles:
        assert needle in text, text
    return text


def accepted(data: bytes) -> m.Message:
    """Both decoders accept ``data`` and make the same message of it."""
    fast, reference = outcomes(data)
    assert fast[0] == "ok", fast
    assert reference[0] == "ok", reference
    assert_messages_equal(fast[1], reference[1])
    assert fast[1].header == reference[1].header
    msg: m.Message = fast[1]
    return msg


def with_raw_field(msg: m.Message, name: str, raw: bytes) -> bytes:
    """A message's bytes with field ``name`` (new or replacing one) holding msgpack ``raw``."""
    obj = to_map(msg)
    obj.pop(name, None)
    entries = b"".join(pack(k) + pack(v) for k, v in obj.items()) + pack(name) + raw
    count = len(obj) + 1
    head = bytes([0x80 | count]) if count < 16 else b"\xde" + struct.pack(">H", count)
    return head + entries


def nested_arrays(levels: int) -> bytes:
    """``levels`` msgpack arrays, each holding the next; the innermost is empty."""
    return b"\x91" * (levels - 1) + b"\x90"


def nested_maps(levels: int) -> bytes:
    """``levels`` msgpack maps, each holding the next under "a"; the innermost is empty."""
    return b"\x81\xa1a" * (levels - 1) + b"\x80"


def test_the_limits_are_the_documented_ones() -> None:
    assert (m.MAX_DEPTH, m.INT64_MAX, m.INT64_MIN) == (DEPTH_LIMIT, INT64_MAX, INT64_MIN)
    for cls in m.REGISTRY.values():
        for f in dataclasses.fields(cls):  # type: ignore[arg-type]
            spec = f.metadata.get("spec")
            if isinstance(spec, m.Spec) and spec.kind in ("int", "dict"):
                assert spec.lo is not None and spec.hi is not None, (cls.TYPE, f.name)
                assert INT64_MIN <= spec.lo <= spec.hi <= INT64_MAX, (cls.TYPE, f.name)


# --------------------------------------------------------------------------------------------
# Extensions anywhere
# --------------------------------------------------------------------------------------------

ODD_EXT = msgpack.ExtType(5, b"\x00\x01")
TIMESTAMP = msgpack.Timestamp(1_767_225_600, 0)  # msgpack's extension type -1


@pytest.mark.parametrize(
    ("where", "make"),
    [
        ("field 'zz_new'", lambda ext: tampered(_heartbeat(), zz_new=ext)),
        ("field 'zz_new'[2]", lambda ext: tampered(_heartbeat(), zz_new=[1, "a", ext])),
        ("field 'zz_new'[0]['b'][1]", lambda ext: tampered(_heartbeat(), zz_new=[{"b": [0, ext]}])),
        ("field 'counters'['received']",
         lambda ext: tampered(_heartbeat(), counters={"received": ext})),
        ("field 'header'['zz']", lambda ext: tampered(
            _heartbeat(), header=to_map(_heartbeat())["header"] | {"zz": ext})),
        ("field 'x_m'", lambda ext: tampered(_vehicle_state(), x_m=ext)),
        ("field 'state'", lambda ext: tampered(_heartbeat(), state=ext)),
    ],
)  # fmt: skip
@pytest.mark.parametrize("ext", [ODD_EXT, TIMESTAMP], ids=["type-5", "timestamp"])
def test_no_other_extension_anywhere(where: str, make: Callable[[Any], bytes], ext: Any) -> None:
    text = refused(make(ext), "malformed", where)
    assert "extension type 5" in text if ext is ODD_EXT else "extension type -1" in text


@pytest.mark.parametrize(
    ("ext", "kind"),
    [
        (raw_ext(b"h", (1,), b"\x00\x00"), "malformed"),  # unknown dtype byte
        (raw_ext(b"d", (1,) * 5, bytes(8)), "malformed"),  # 5 dimensions
        (raw_ext(b"d", (3,), bytes(16)), "truncated"),  # data shorter than its shape
        (raw_ext(b"d", (1,), bytes(16)), "malformed"),  # data longer than its shape
        (raw_ext(b"B", (1 << 21,), b""), "oversized"),  # beyond 2**20 elements
        (msgpack.ExtType(1, b""), "truncated"),  # no head
    ],
    ids=["dtype", "ndim", "short", "long", "elements", "empty"],
)
def test_a_typed_array_in_an_unknown_field_must_be_well_formed(ext: Any, kind: str) -> None:
    refused(tampered(_heartbeat(), zz_new=ext), kind, "field 'zz_new'")
    refused(tampered(_heartbeat(), zz_new={"deeper": [ext]}), kind, "field 'zz_new'['deeper'][0]")
    # A well-formed one, of any dtype and shape, values unchecked, is ignored.
    extras = {
        "zz_array": typed_array(np.zeros((2, 3)), "i8"),
        "zz_nested": [{"a": typed_array([np.nan, np.inf])}, typed_array(np.zeros(0), "u1")],
        "zz_empty": raw_ext(b"?", (), b"\x01"),  # 0 dimensions: one element
    }
    assert_messages_equal(accepted(tampered(_heartbeat(), **extras)), _heartbeat())


def test_a_long_key_is_shortened_in_the_error() -> None:
    key = "k" * 5000
    text = refused(tampered(_heartbeat(), zz_new={key: ODD_EXT}), "malformed", "field 'zz_new'")
    assert key not in text


# --------------------------------------------------------------------------------------------
# Integers: int64, within each field's range
# --------------------------------------------------------------------------------------------


def _header(**changes: Any) -> dict[str, Any]:
    header: dict[str, Any] = to_map(_heartbeat())["header"]
    return header | changes


@pytest.mark.parametrize(
    ("where", "make"),
    [
        ("header stamp_ns", lambda v: tampered(_heartbeat(), header=_header(stamp_ns=v))),
        ("header seq", lambda v: tampered(_heartbeat(), header=_header(seq=v))),
        ("field 'pid'", lambda v: tampered(_heartbeat(), pid=v)),
        ("field 'sweep_index'", lambda v: tampered(_raw_scan(), sweep_index=v)),
        ("field 'sweeps'", lambda v: tampered(_head_state(), sweeps=v)),
        ("field 'command_seq'", lambda v: tampered(_head_state(), command_seq=v)),
        ("field 'counters'['received']",
         lambda v: tampered(_heartbeat(), counters={"received": v})),
    ],
)  # fmt: skip
def test_integers_beyond_int64_are_out_of_range(where: str, make: Callable[[int], bytes]) -> None:
    msg = accepted(make(INT64_MAX))  # the limit is in range, and is sent on as it came
    assert m.decode(msg.to_wire()).to_wire() == msg.to_wire()
    for value in (INT64_MAX + 1, UINT64_MAX):  # msgpack's uint64
        refused(make(value), "out_of_range", where, str(value))


def test_a_counter_below_zero_is_out_of_range() -> None:
    refused(
        tampered(_heartbeat(), counters={"lost": -1}), "out_of_range", "field 'counters'['lost']"
    )
    refused(tampered(_heartbeat(), counters={"lost": INT64_MIN}), "out_of_range")


def test_an_int_field_without_bounds_is_bounded_by_int64(monkeypatch: pytest.MonkeyPatch) -> None:
    @dataclasses.dataclass(frozen=True, eq=False, kw_only=True)
    class Tally(m.Message):
        header: m.Header
        total: int = m.i64()

    Tally.TYPE, Tally.VERSION = "tally", 1
    monkeypatch.setitem(m.REGISTRY, "tally/1", Tally)
    lowest = accepted(Tally(header=m.Header(), total=INT64_MIN).to_wire())
    assert isinstance(lowest, Tally) and lowest.total == INT64_MIN
    refused(Tally(header=m.Header(), total=INT64_MAX + 1).to_wire(), "out_of_range", "'total'")


# --------------------------------------------------------------------------------------------
# Nesting depth
# --------------------------------------------------------------------------------------------


def test_nesting_at_the_limit_is_taken_and_one_level_more_is_not() -> None:
    # The message's map is level 1, so a field may hold 31 levels of arrays or maps.
    for make in (nested_arrays, nested_maps):
        fits = with_raw_field(_heartbeat(), "zz_new", make(DEPTH_LIMIT - 1))
        assert_messages_equal(accepted(fits), _heartbeat())
        too_deep = with_raw_field(_heartbeat(), "zz_new", make(DEPTH_LIMIT))
        refused(too_deep, "oversized", "field 'zz_new'", f"deeper than {DEPTH_LIMIT} levels")


@pytest.mark.parametrize("levels", [100, 1_000, 100_000])
@pytest.mark.parametrize(
    ("msg", "name"),
    [
        (_heartbeat(), "zz_new"),  # a field the reader does not know
        (_vehicle_state(), "x_m"),  # a float field
        (_filtered_scan(), "points_xy"),  # an array field
        (_heartbeat(), "counters"),  # a map field
    ],
    ids=["unknown", "float", "array", "map"],
)
def test_deep_nesting_is_oversized_never_a_recursion_error(
    msg: m.Message, name: str, levels: int
) -> None:
    refused(with_raw_field(msg, name, nested_arrays(levels)), "oversized", "deeper than")


def test_a_deeply_nested_message_is_oversized() -> None:
    for data in (nested_arrays(100_000), nested_maps(100_000)):
        refused(data, "oversized", f"deeper than {DEPTH_LIMIT} levels")


# --------------------------------------------------------------------------------------------
# Both decoders on many hostile inputs
# --------------------------------------------------------------------------------------------

_EDGE_INTS = [INT64_MAX, INT64_MAX + 1, UINT64_MAX, INT64_MIN, -1, 0]


def _hostile_value(rng: np.random.Generator, depth: int) -> Any:
    """A random msgpack value: plain, an extension, or a map or array of such values."""
    pick = int(rng.integers(10))
    if pick == 0 and depth < DEPTH_LIMIT + 3:
        return [_hostile_value(rng, depth + 1) for _ in range(int(rng.integers(0, 3)))]
    if pick == 1 and depth < DEPTH_LIMIT + 3:
        return {f"k{i}": _hostile_value(rng, depth + 1) for i in range(int(rng.integers(0, 3)))}
    if pick == 2:
        return msgpack.ExtType(
            int(rng.choice([1, 1, 2, 5, 127])), b"d\x01\x01\x00\x00\x00" + bytes(8)
        )
    if pick == 3:
        code = int(rng.integers(4))
        return raw_ext(b"dq?h"[code : code + 1], (int(rng.integers(3)),), bytes(8))
    if pick == 4:
        return TIMESTAMP
    if pick == 5:
        return _EDGE_INTS[int(rng.integers(len(_EDGE_INTS)))]
    return [1.5, "s", None, True, b"b"][int(rng.integers(5))]


def _deep(rng: np.random.Generator) -> Any:
    """A value nested around the depth limit, with something hostile at the bottom."""
    value = _hostile_value(rng, DEPTH_LIMIT)
    for _ in range(int(rng.integers(DEPTH_LIMIT - 3, DEPTH_LIMIT + 3))):
        value = [value] if rng.integers(2) else {"n": value}
    return value


def _hostile(rng: np.random.Generator, msg: m.Message) -> bytes:
    obj = to_map(msg)
    names = [k for k in obj if k != "type"] + ["zz_new", "zz_new"]
    for _ in range(int(rng.integers(1, 3))):
        name = names[int(rng.integers(len(names)))]
        how = int(rng.integers(4))
        if how == 0:
            obj[name] = _hostile_value(rng, 2)
        elif how == 1:
            obj[name] = _deep(rng)
        elif how == 2 and isinstance(obj.get(name), dict):  # header or counters
            key = ["stamp_ns", "seq", "received", "zz"][int(rng.integers(4))]
            obj[name] = dict(obj[name]) | {key: _hostile_value(rng, 3)}
        elif how == 2:  # an integer at and beyond int64's limits, in any field
            obj[name] = _EDGE_INTS[int(rng.integers(len(_EDGE_INTS)))]
        else:
            obj[name] = [_hostile_value(rng, 3) for _ in range(3)]
    packed: bytes = msgpack.packb(obj, use_bin_type=True)
    return packed


def test_both_decoders_agree_on_hostile_inputs() -> None:
    rng = np.random.default_rng(HOSTILE_SEED)
    messages = [example(tag) for tag in TAGS]
    kinds: Counter[str] = Counter()
    for i in range(HOSTILE_INPUTS):
        data = _hostile(rng, messages[i % len(messages)])
        fast, reference = outcomes(data)
        assert fast[0] == reference[0], f"fast {fast}, reference {reference}, input {data.hex()}"
        kinds[fast[0]] += 1
        if fast[0] == "ok":
            assert_messages_equal(fast[1], reference[1])
        else:
            assert fast[1] == reference[1]
            assert "\n" not in fast[1]
    print(f"hostile inputs: {dict(sorted(kinds.items()))}")
    for kind in ("ok", "malformed", "oversized", "out_of_range", "truncated"):
        assert kinds[kind] > HOSTILE_INPUTS // 100, dict(kinds)
