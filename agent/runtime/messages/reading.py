"""Turning a decoded wire struct into its message, checking what msgspec could not.

msgspec has checked the scalars, strings and counters as it parsed (see :mod:`.codec`).
Left are the header (a map, checked here: ``stamp_ns`` and ``seq`` are int64s of 0 or more),
the typed arrays, and building the message.

The arrays' msgpack bytes (extension framing, extension type, payload head, data), as they
came, go into one buffer, each after the padding that makes its data start aligned. Then,
for all arrays at once:

* framings and payload heads are compared with what the sizes of the named dimensions
  (``n`` samples, ``k`` features) imply: one comparison per array covers the extension
  type, its length, the dtype, the number of dimensions and every dimension;
* a bounded uint8 array's bytes are checked against the values it may hold
  (``bytes.translate``);
* the values of the arrays of one dtype are checked by a few reductions over the buffer seen
  as that dtype (``ufunc.reduceat``, one segment per array): floats are finite, or NaN where
  allowed, and every value lies within its field's bounds;
* the arrays become read-only views of the buffer, which is immutable and never the sender's.

Anything that does not match is left to the reference decoder (:mod:`.checks`), which
names the problem. The code doing all this for a message type is generated, once per message
type and set of empty arrays, and compiled; the sizes of one message reach it as the
variables of a closure, made once per distinct set of sizes. For a 256-sample filtered scan,
the array steps unrolled so took 13.5 µs against 20.5 µs driven by loops over a description
of the arrays; generating the header's checks and the message's making with them saved 3 µs
more.
"""

from __future__ import annotations

import math
import struct
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import msgspec
import numpy as np

from agent.runtime.messages import arrays
from agent.runtime.messages.schema import (
    INT64_MAX,
    MAX_ARRAY_ELEMENTS,
    MAX_NAME_CHARS,
    Header,
    Message,
    Spec,
)

_DBL_MAX = sys.float_info.max
_U32 = struct.Struct("<I")
_MAX_READERS = 64  # per message type; more distinct sizes start the cache afresh


@dataclass(frozen=True)
class ArrayField:
    """An array field of a message type, as the checks need it."""

    index: int  # among the message's fields
    dtype: np.dtype[Any]  # on the wire
    dims: tuple[str | int, ...]
    lo: float  # bounds; for floats ±DBL_MAX where none was declared, so that ±inf fail them
    hi: float
    allow_nan: bool

    @classmethod
    def from_spec(cls, index: int, spec: Spec) -> ArrayField:
        """The field ``index`` of a message type, declared as ``spec``."""
        dt = arrays.wire_dtype(spec.dtype)
        none = _DBL_MAX if dt.kind == "f" else math.inf
        lo = -none if spec.lo is None else spec.lo
        hi = none if spec.hi is None else spec.hi
        return cls(index, dt, spec.dims, lo, hi, spec.allow_nan and dt.kind == "f")

    @property
    def byte_set(self) -> bytes | None:
        """For a bounded uint8 array, the bytes it may hold; else ``None``."""
        if self.dtype != np.uint8 or (self.lo <= 0 and self.hi >= 255):
            return None
        return bytes(range(max(0, math.ceil(self.lo)), min(255, math.floor(self.hi)) + 1))

    @property
    def reduced(self) -> bool:
        """Whether reductions check the values: floats always (finiteness), integers where a
        bound excludes some of the dtype's values and no byte set checks them."""
        if self.dtype.kind == "f":
            return True
        if self.byte_set is not None or self.dtype.kind not in "iu":
            return False
        info = np.iinfo(self.dtype)
        return self.lo > info.min or self.hi < info.max


@dataclass(frozen=True)
class _Pass:
    """One reduction over the arrays of one dtype and the bound each array's result must meet.

    ``within`` (``>=`` a lower bound, ``<=`` an upper one) fails a NaN result; ``beyond``
    (``<``, ``>``) lets it pass.
    """

    reduce_at: Callable[..., Any]  # a ufunc's reduceat
    members: tuple[int, ...]  # the arrays, by their place in the buffer
    bound: str  # "lo" or "hi"
    op: str  # the comparison that a result must pass ("within") or must not ("beyond")
    within: bool


def _passes(
    order: Sequence[ArrayField], group: Sequence[int], empty: Sequence[bool]
) -> list[_Pass]:
    """The reductions that check the arrays ``group`` (places in ``order``, one dtype).

    Floats: the least of the arrays that may not hold NaN with ``minimum``, which carries NaN
    (a NaN result fails); the least of those that may with ``fmin``, which skips it (a NaN
    result means every value is NaN, and passes); the greatest of all with ``fmax`` (a NaN
    in an array that may not hold one has failed already). Integers: ``minimum`` and
    ``maximum``, where a bound asks. Empty arrays have nothing to check.
    """
    checked = [k for k in group if order[k].reduced and not empty[k]]
    if not checked:
        return []
    dt = order[checked[0]].dtype
    if dt.kind != "f":
        info = np.iinfo(dt)
        passes = []
        if any(order[k].lo > info.min for k in checked):
            passes.append(_Pass(np.minimum.reduceat, tuple(checked), "lo", ">=", True))
        if any(order[k].hi < info.max for k in checked):
            passes.append(_Pass(np.maximum.reduceat, tuple(checked), "hi", "<=", True))
        return passes
    strict = tuple(k for k in checked if not order[k].allow_nan)
    nan_allowed = tuple(k for k in checked if order[k].allow_nan)
    passes = []
    if strict:
        passes.append(_Pass(np.minimum.reduceat, strict, "lo", ">=", True))
    if nan_allowed:
        passes.append(_Pass(np.fmin.reduceat, nan_allowed, "lo", "<", False))
    passes.append(_Pass(np.fmax.reduceat, tuple(checked), "hi", ">", False))
    return passes


def _groups(order: Sequence[ArrayField]) -> list[list[int]]:
    """The places in ``order`` of the arrays of each dtype."""
    by_dtype: dict[np.dtype[Any], list[int]] = {}
    for k, f in enumerate(order):
        by_dtype.setdefault(f.dtype, []).append(k)
    return list(by_dtype.values())


def _source(
    names: Sequence[str],
    header: int,
    order: Sequence[ArrayField],
    empty: Sequence[bool],
    fills_dict: tuple[bool, bool],
) -> str:
    """The source of ``make(kw)``, which returns ``read(wire)`` for one set of array sizes.

    ``read`` turns a message type's wire struct (fields ``names``, the header at ``header``,
    arrays ``order`` in buffer order, of which ``empty`` ones hold no element) into the
    message, or returns ``None`` at the first mismatch. ``fills_dict``: whether the header
    and the message can be made by setting their ``__dict__`` (else through ``__init__``).

    Names taken from ``kw``: per array ``k`` the padding before its bytes ``P{k}``, their
    expected start ``Q{k}`` (framing, extension type, payload head) and place ``O{k}``, its
    data's first element and the one after its last ``A{k}``, ``B{k}``, its shape ``S{k}``,
    bounds ``LO{k}``, ``HI{k}``, for a byte set the data's span ``BS{k}``, ``BE{k}`` and the
    bytes allowed ``Y{k}``; per dtype ``g`` the dtype ``D{g}`` and the count of its elements
    in the buffer ``C{g}``; per pass ``p`` the reduction ``R{g}_{p}`` and the segments'
    edges ``E{g}_{p}``; and the helpers of :data:`_HELPERS`.
    """
    used: list[str] = [*_HELPERS, "CLS"]
    body: list[str] = []

    def fail_if(condition: str) -> None:
        body.extend([f"if {condition}:", "    return None"])

    def use(*new: str) -> None:
        used.extend(n for n in new if n not in used)

    def build(cls: str, fields: str, fill: bool, into: str) -> None:
        if fill:
            body.extend([f"{into} = new({cls})", f"set_attr({into}, '__dict__', {fields})"])
        else:
            body.append(f"{into} = {cls}(**{fields})")

    value = {i: f"v{i}" for i in range(len(names))}
    body.append("".join(f"{value[i]}, " for i in range(len(names))) + "= astuple(wire)")
    h = value[header]
    body.append(f"stamp, seq = {h}.get('stamp_ns'), {h}.get('seq')")
    body.append(f"frame, source = {h}.get('frame_id'), {h}.get('source')")
    fail_if(
        "not (stamp.__class__ is int and seq.__class__ is int"
        " and 0 <= stamp <= INT64_MAX and 0 <= seq <= INT64_MAX"
        " and frame.__class__ is str and source.__class__ is str"
        " and len(frame) <= MAX_NAME_CHARS and len(source) <= MAX_NAME_CHARS)"
    )
    fields = "{'stamp_ns': stamp, 'seq': seq, 'frame_id': frame, 'source': source}"
    build("HEADER", fields, fills_dict[0], "header")
    value[header] = "header"
    ks = range(len(order))
    if order:
        use(*(f"P{k}" for k in ks), *(f"Q{k}" for k in ks), *(f"O{k}" for k in ks))
        pieces = ", ".join(f"P{k}, {value[order[k].index]}" for k in ks)
        body.append(f"buf = join(({pieces},))")
        # An array's framing holds its length: where the first array's start is as expected,
        # so is its length, hence the place of the next, and so on.
        fail_if("not (" + " and ".join(f"buf.startswith(Q{k}, O{k})" for k in ks) + ")")
    for k in ks:
        if order[k].byte_set is not None and not empty[k]:
            use(f"BS{k}", f"BE{k}", f"Y{k}")
            fail_if(f"buf[BS{k}:BE{k}].translate(None, Y{k})")
    for g, group in enumerate(_groups(order)):
        use(f"D{g}", f"C{g}")
        body.append(f"flat = frombuffer(buf, D{g}, C{g})")
        for p, check in enumerate(_passes(order, group, empty)):
            use(f"R{g}_{p}", f"E{g}_{p}")
            body.append(f"r = R{g}_{p}(flat, E{g}_{p}).tolist()")
            bound = "LO" if check.bound == "lo" else "HI"
            use(*(f"{bound}{k}" for k in check.members))
            tests = [f"r[{2 * j}] {check.op} {bound}{k}" for j, k in enumerate(check.members)]
            fail_if("not (" + " and ".join(tests) + ")" if check.within else " or ".join(tests))
        for k in group:
            use(f"A{k}", f"B{k}")
            view = f"flat[A{k}:B{k}]"
            if len(order[k].dims) != 1:
                use(f"S{k}")
                view += f".reshape(S{k})"
            body.append(f"a{k} = {view}")
            value[order[k].index] = f"a{k}"
    entries = ", ".join(f"{name!r}: {value[i]}" for i, name in enumerate(names))
    build("CLS", "{" + entries + "}", fills_dict[1], "msg")
    body.append("return msg")
    return "\n".join(
        ["def make(kw):"]
        + [f"    {name} = kw[{name!r}]" for name in used]
        + ["", "    def read(wire):"]
        + [f"        {line}" for line in body]
        + ["", "    return read"]
    )


def _values(
    order: Sequence[ArrayField], shapes: Sequence[tuple[int, ...]], empty: Sequence[bool]
) -> dict[str, Any]:
    """What the array names of :func:`_source` stand for, for arrays of ``shapes``."""
    kw: dict[str, Any] = {}
    cursor = 0
    for k, (f, shape) in enumerate(zip(order, shapes, strict=True)):
        size = f.dtype.itemsize
        n = math.prod(shape)
        start = arrays.ext_start(f.dtype, shape)
        pad = -(cursor + len(start)) % size
        data = cursor + pad + len(start)
        kw |= {f"P{k}": bytes(pad), f"Q{k}": start}
        kw |= {f"O{k}": cursor + pad, f"A{k}": data // size, f"B{k}": data // size + n}
        kw |= {f"S{k}": shape, f"LO{k}": f.lo, f"HI{k}": f.hi}
        if f.byte_set is not None:
            kw |= {f"BS{k}": data, f"BE{k}": data + n, f"Y{k}": f.byte_set}
        cursor = data + n * size
    for g, group in enumerate(_groups(order)):
        dt = order[group[0]].dtype
        count = cursor // dt.itemsize
        kw |= {f"D{g}": dt, f"C{g}": count}
        for p, check in enumerate(_passes(order, group, empty)):
            edges = [edge for k in check.members for edge in (kw[f"A{k}"], kw[f"B{k}"])]
            if edges[-1] == count:  # the last array ends the buffer
                edges.pop()
            kw |= {f"R{g}_{p}": check.reduce_at, f"E{g}_{p}": np.array(edges, np.intp)}
    return kw


def _fills_dict(cls: type[Any]) -> bool:
    """Whether setting an instance's ``__dict__`` does what the class's ``__init__`` does.

    A frozen dataclass's ``__init__`` sets each field through ``object.__setattr__``; where
    the class adds nothing to that (no ``__post_init__``, no slots), setting the whole
    ``__dict__`` at once does the same, several times faster.
    """
    return not hasattr(cls, "__post_init__") and "__slots__" not in vars(cls)


_HELPERS: dict[str, Any] = {
    "astuple": msgspec.structs.astuple,
    "new": object.__new__,
    "set_attr": object.__setattr__,
    "join": b"".join,
    "frombuffer": np.frombuffer,
    "MAX_NAME_CHARS": MAX_NAME_CHARS,
    "INT64_MAX": INT64_MAX,
    "HEADER": Header,
}


class Reader:
    """Makes messages of one type from their wire structs.

    Parameters
    ----------
    cls
        The message type.
    names
        Its fields, in the order of the wire struct's.
    specs
        Each field's spec (the header's included).
    """

    def __init__(self, cls: type[Message], names: Sequence[str], specs: Sequence[Spec]) -> None:
        self.cls = cls
        self.tag = f"{cls.TYPE}/{cls.VERSION}"
        self.names = tuple(names)
        self.header = self.names.index("header")
        fields = [ArrayField.from_spec(i, s) for i, s in enumerate(specs) if s.kind == "array"]
        # Largest item size first, so that each array's data starts aligned with little
        # padding; arrays of one dtype together, so that reductions span little else.
        self.order = tuple(sorted(fields, key=lambda f: (-f.dtype.itemsize, f.dtype.str)))
        # Where each named dim's size is first read: (field name, offset in its payload).
        sources: dict[str, tuple[str, int]] = {}
        for f in fields:
            for axis, dim in enumerate(f.dims):
                if isinstance(dim, str):
                    sources.setdefault(dim, (self.names[f.index], 2 + 4 * axis))
        self.dim_names = tuple(sources)
        self.size_sources = tuple(sources.values())
        self.fills_dict = (_fills_dict(Header), _fills_dict(cls))
        self._makers: dict[tuple[bool, ...], Callable[[dict[str, Any]], Any]] = {}
        self._readers: dict[tuple[int, ...], Callable[[Any], Message | None]] = {}

    def read(self, wire: Any) -> Message | None:
        """The message of a wire struct, or ``None`` if it needs the reference decoder."""
        sizes = []
        for name, at in self.size_sources:
            raw = memoryview(getattr(wire, name))
            framing = arrays.FRAMING_LENGTH.get(raw[0]) if raw else None  # empty: missing
            if framing is None or len(raw) < framing + at + 4:
                return None
            sizes.append(_U32.unpack_from(raw, framing + at)[0])
        key = tuple(sizes)
        reader = self._readers.get(key)
        if reader is None:
            made = self._reader(dict(zip(self.dim_names, key, strict=True)))
            if made is None:
                return None
            if len(self._readers) >= _MAX_READERS:
                self._readers.clear()
            reader = self._readers[key] = made
        return reader(wire)

    def _reader(self, sizes: dict[str, int]) -> Callable[[Any], Message | None] | None:
        """The reader for arrays of ``sizes``; ``None`` if an array would be too large."""
        shapes = [tuple(d if isinstance(d, int) else sizes[d] for d in f.dims) for f in self.order]
        for shape in shapes:
            if math.prod(shape) > MAX_ARRAY_ELEMENTS or any(d > MAX_ARRAY_ELEMENTS for d in shape):
                return None
        empty = tuple(math.prod(shape) == 0 for shape in shapes)
        make = self._makers.get(empty)
        if make is None:
            source = _source(self.names, self.header, self.order, empty, self.fills_dict)
            namespace: dict[str, Any] = {}
            exec(compile(source, f"<read {self.cls.__name__}>", "exec"), namespace)
            make = self._makers[empty] = namespace["make"]
        kw = _HELPERS | {"CLS": self.cls} | _values(self.order, shapes, empty)
        reader: Callable[[Any], Message | None] = make(kw)
        return reader
