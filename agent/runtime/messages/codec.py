"""Encoding and decoding messages, in msgspec's compiled msgpack code.

:func:`encode` writes a message's wire map (type tag, header, the fields in declaration
order): msgspec encodes the scalars, strings and counters, and each typed array goes in
straight from its numpy array, after the bytes before its data.

:func:`decode` decodes into msgspec structs generated from the message types' field specs,
so that msgspec checks, as it parses, everything but the header and the arrays: the type
tag, presence and type of every field, ranges, finiteness, string lengths, choices,
counters. :mod:`.reading` checks the header, and the arrays together: their framings and
heads against the shapes their shared sizes imply, their values with a few reductions over
one buffer that holds all of them. A message this does not accept outright goes to
:func:`.checks.decode`, the reference decoder, which raises the precise
:class:`~agent.errors.MessageError` or, for the rarer forms that are valid (fields a newer
writer added, maps or arrays in longer encodings than needed), decodes it.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import operator
import sys
from collections.abc import Callable
from typing import Annotated, Any, Literal, TypeVar

import msgspec
import numpy as np
from msgspec import Meta
from msgspec.msgpack import Ext

from agent.runtime.messages import arrays, checks
from agent.runtime.messages.reading import Reader
from agent.runtime.messages.schema import (
    INT64_MAX,
    MAX_MAP_ITEMS,
    MAX_MESSAGE_BYTES,
    MAX_NAME_CHARS,
    MAX_STRING_CHARS,
    REGISTRY,
    Message,
    Spec,
)

M = TypeVar("M", bound=Message)

peek_type = checks.peek_type


# -------------------------------------------------------------------------------- encoding
def _default(obj: Any) -> Any:
    """msgspec's hook for what it does not encode itself: numpy arrays and scalars, and
    subclasses of str, int and float."""
    if isinstance(obj, np.ndarray):
        return Ext(arrays.ARRAY_EXT_CODE, arrays.pack(obj, arrays.wire_dtype(obj.dtype.str)))
    if isinstance(obj, np.generic):
        return obj.item()
    for base in (str, int, float):  # subclasses, as msgpack writes them
        if isinstance(obj, base):
            return base(obj)
    raise TypeError(f"cannot encode {type(obj).__name__}")


_ENCODER = msgspec.msgpack.Encoder(enc_hook=_default)


def _counts(value: dict[Any, Any]) -> dict[str, int]:
    return {str(k): int(v) for k, v in value.items()}


# What a field's value becomes on the wire, by its kind (a string goes as it is).
_CONVERT: dict[str, str] = {"float": "float", "int": "int", "bool": "bool", "dict": "counts"}
_MAX_STARTS = 64  # shapes remembered per array field; more distinct ones start afresh

_Writer = Callable[[Message, int | None, str | None, int | None], bytes]
_WRITERS: dict[type[Message], _Writer] = {}


def _map_head(entries: int) -> bytes:
    """msgpack's head of a map of ``entries`` (fixmap or map 16, as msgspec writes it)."""
    return bytes((0x80 | entries,)) if entries < 16 else b"\xde" + entries.to_bytes(2, "big")


def _starter(key: bytes, dt: np.dtype[Any]) -> tuple[dict[tuple[int, ...], bytes], Any]:
    """For one array field: the bytes before each shape's data (the field's key, the
    extension's framing, type and payload head), kept per shape, and how to make them."""
    starts: dict[tuple[int, ...], bytes] = {}

    def start(shape: tuple[int, ...]) -> bytes:
        if len(starts) >= _MAX_STARTS:
            starts.clear()
        made = starts[shape] = key + arrays.ext_start(dt, shape)
        return made

    return starts, start


def _writer(cls: type[Message]) -> _Writer:
    """:func:`encode` for one message type.

    The wire map is the tag, the header, then the fields in declaration order. Its source is
    generated once per type: each run of fields other than arrays is encoded by msgspec as a
    small map whose head is dropped, and each array goes in as the bytes before its data
    (kept per shape) and its data, read straight from the array; one join makes the message.
    (One map of msgspec extensions, each array copied into its own bytes, took twice as long
    for a filtered scan: 10 µs against 5.)
    """
    namespace: dict[str, Any] = {
        "encode": _ENCODER.encode, "join": b"".join, "asc": np.ascontiguousarray,
        "counts": _counts, "TAG": f"{cls.TYPE}/{cls.VERSION}",
    }  # fmt: skip
    plans = [p for p in checks.field_plans(cls) if p.spec.kind != "header"]
    namespace["HEAD"] = _map_head(2 + len(plans))
    body = ["h = msg.header"]
    run = [
        "'type': TAG",
        "'header': {'stamp_ns': int(h.stamp_ns if stamp_ns is None else stamp_ns),"
        " 'seq': int(h.seq if seq is None else seq), 'frame_id': h.frame_id,"
        " 'source': h.source if source is None else source}",
    ]
    pieces = ["HEAD"]

    def end_run() -> None:
        if run:
            body.append(f"m{len(pieces)} = encode({{{', '.join(run)}}})")
            pieces.append(f"m{len(pieces)}[{len(_map_head(len(run)))}:]")
            run.clear()

    for i, plan in enumerate(plans):
        name, kind = plan.name, plan.spec.kind
        if kind == "array":
            end_run()
            dt = arrays.wire_dtype(plan.spec.dtype)
            namespace[f"D{i}"] = dt
            namespace[f"C{i}"], namespace[f"start{i}"] = _starter(_ENCODER.encode(name), dt)
            body.append(f"a{i} = asc(msg.{name}, dtype=D{i})")
            body.append(f"s{i} = C{i}.get(a{i}.shape) or start{i}(a{i}.shape)")
            pieces += [f"s{i}", f"a{i}"]
        elif kind in _CONVERT:
            run.append(f"{name!r}: {_CONVERT[kind]}(msg.{name})")
        else:
            run.append(f"{name!r}: msg.{name}")
    end_run()
    body.append(f"return join(({', '.join(pieces)},))")
    source = "\n".join(["def write(msg, seq, source, stamp_ns):"] + [f"    {x}" for x in body])
    exec(compile(source, f"<encode {cls.__name__}>", "exec"), namespace)
    writer: _Writer = namespace["write"]
    _WRITERS[cls] = writer
    return writer


def encode(
    msg: Message,
    *,
    seq: int | None = None,
    source: str | None = None,
    stamp_ns: int | None = None,
) -> bytes:
    """A message as msgpack bytes (see :mod:`agent.runtime.messages`).

    ``seq``, ``source`` and ``stamp_ns``, where given, replace the header's on the wire.

    Raises
    ------
    TypeError
        A field holds a value of a type that cannot be encoded.
    """
    writer = _WRITERS.get(msg.__class__) or _writer(msg.__class__)
    return writer(msg, seq, source, stamp_ns)


# ------------------------------------------------------------------------ the wire structs
_DBL_MAX = sys.float_info.max
_Text = Annotated[str, Meta(max_length=MAX_STRING_CHARS)]
_Name = Annotated[str, Meta(max_length=MAX_NAME_CHARS)]
# The header is read as a bounded map and checked in .reading: a struct would also take a map
# of more than MAX_MAP_ITEMS entries that repeat its keys.
_WireHeader = Annotated[dict[_Text, int | _Text], Meta(max_length=MAX_MAP_ITEMS)]
_Count = Annotated[int, Meta(ge=0, le=INT64_MAX)]  # as schema.counters declares
_Counters = Annotated[dict[_Name, _Count], Meta(max_length=MAX_MAP_ITEMS)]


def _int_type(spec: Spec) -> Any:
    """An integer within a spec's bounds (which are never beyond int64's)."""
    lo = None if spec.lo is None else math.ceil(spec.lo)
    hi = None if spec.hi is None else math.floor(spec.hi)
    return Annotated[int, Meta(ge=lo, le=hi)]


def _wire_type(spec: Spec) -> Any:
    """What msgspec accepts for a field: exactly what the reference decoder accepts, or less."""
    if spec.kind == "float":  # bounds of ±DBL_MAX refuse inf, and NaN fails every bound
        lo = -_DBL_MAX if spec.lo is None else float(spec.lo)
        hi = _DBL_MAX if spec.hi is None else float(spec.hi)
        return Annotated[float, Meta(ge=lo, le=hi)]
    if spec.kind == "int":
        return _int_type(spec)
    if spec.kind == "bool":
        return bool
    if spec.kind == "str":
        return Literal[spec.choices] if spec.choices else _Text
    if spec.kind == "dict":
        return _Counters
    if spec.kind == "array":  # its msgpack bytes as they are, checked in .reading
        return msgspec.Raw
    raise TypeError(f"unsupported field kind {spec.kind}")


def _wire_struct(cls: type[Message]) -> type[msgspec.Struct]:
    """The msgspec struct of a message type's wire map (its tag is the ``type`` entry)."""
    defaults = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    fields: list[Any] = []
    for plan in checks.field_plans(cls):
        f = defaults[plan.name]
        if plan.spec.kind == "header":
            fields.append((plan.name, _WireHeader))
        elif plan.required:
            fields.append((plan.name, _wire_type(plan.spec)))
        elif plan.spec.kind == "array":  # missing (empty): left to the reference decoder
            fields.append((plan.name, msgspec.Raw, msgspec.Raw()))
        elif f.default_factory is not dataclasses.MISSING:
            factory = msgspec.field(default_factory=f.default_factory)
            fields.append((plan.name, _wire_type(plan.spec), factory))
        else:
            fields.append((plan.name, _wire_type(plan.spec), f.default))
    return msgspec.defstruct(
        f"{cls.__name__}Wire",
        fields,
        tag_field="type",
        tag=f"{cls.TYPE}/{cls.VERSION}",
        forbid_unknown_fields=True,  # unknown fields go to the reference decoder
        kw_only=True,
        gc=False,
    )


# -------------------------------------------------------------------------------- decoding
# The decoder of every registered type, with the reader of each type's wire struct, and how
# many types there were when they were made: a type registered or removed since makes them
# again. (Should a type be removed and another registered in between, the new one's messages
# go to the reference decoder, and a reader whose type the registry no longer holds under its
# tag is not used.)
_Fast = tuple[int, msgspec.msgpack.Decoder[Any], dict[type[msgspec.Struct], Reader]]
_fast: _Fast | None = None


def _reader(cls: type[Message]) -> Reader:
    """The reader of a message type's wire struct (whose fields are the type's, in order)."""
    plans = checks.field_plans(cls)
    return Reader(cls, [p.name for p in plans], [p.spec for p in plans])


def _fast_decoder() -> _Fast:
    """The decoder of every registered type and the readers of their wire structs."""
    global _fast
    fast = _fast
    if fast is None or fast[0] != len(REGISTRY):
        structs = {_wire_struct(cls): cls for cls in REGISTRY.values()}
        union = functools.reduce(operator.or_, structs)
        readers = {s: _reader(cls) for s, cls in structs.items()}
        fast = _fast = (len(REGISTRY), msgspec.msgpack.Decoder(union), readers)
    return fast


_MAP16_LIMIT = MAX_MAP_ITEMS.to_bytes(2, "big")
# What msgspec raises on bytes it does not take: UnicodeDecodeError for invalid UTF-8, and
# RecursionError for a value nested deeper than Python's recursion limit (msgspec skips over
# an array field's value recursively before .reading sees it is no typed array).
_REFUSED = (msgspec.DecodeError, msgspec.ValidationError, UnicodeDecodeError, RecursionError)


def decode(data: bytes, expect: type[M] | None = None) -> M | Message:
    """Decode and validate a message; raise :class:`MessageError` if it is unusable.

    With ``expect``, a message of another type is an error (kind ``unknown_type``).

    Arrays are read-only and aligned. ``data`` that is not ``bytes`` (a ``bytearray``, a
    ``memoryview``) is copied first, so the message never shares memory with a buffer its
    sender may reuse.

    Raises
    ------
    MessageError
        With ``kind`` one of ``MessageError.KINDS``; see docs/interface.md, section 6.
    """
    if data.__class__ is not bytes:
        if not isinstance(data, bytes | bytearray | memoryview):
            return checks.decode(data, expect)
        data = bytes(data)
    # msgspec does not count map entries (a map may repeat its keys), so the top level's
    # count is checked here: a fixmap, or a map 16 within the limit; a map 32 goes to the
    # reference decoder.
    if 0 < len(data) <= MAX_MESSAGE_BYTES and (
        0x80 <= data[0] <= 0x8F or (data[0] == 0xDE and data[1:3] <= _MAP16_LIMIT)
    ):
        _, decoder, readers = _fast_decoder()
        try:
            wire = decoder.decode(data)
            reader = readers[wire.__class__]
            if (expect is None or reader.cls is expect) and REGISTRY.get(reader.tag) is reader.cls:
                msg = reader.read(wire)
                if msg is not None:
                    return msg
        except _REFUSED:
            pass
    return checks.decode(data, expect)
