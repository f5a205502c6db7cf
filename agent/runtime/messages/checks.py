"""The reference decoder: every check, field by field, each failure named precisely.

:func:`decode` parses with msgpack under the size limits of :mod:`.schema`, then looks through
the whole message, fields it does not know included, for what no field may hold anywhere: an
extension other than a well-formed typed array, maps and arrays nested deeper than
:data:`~.schema.MAX_DEPTH`. Then it checks each field of the message type against its
:class:`~.schema.Spec`: presence, type, dtype, shape (arrays sharing a dimension name, such as
``n`` samples, must agree) and range (integers within their bounds, which never exceed
int64's). Any failure raises :class:`agent.errors.MessageError` with a ``kind`` for counting.
It reads everything the wire format allows, unknown fields of newer writers included.

:func:`agent.runtime.messages.codec.decode` is the fast decoder; it hands whatever it does not
accept outright to this one, which either explains the failure or, for the rarer forms it
does not take (unknown fields, say), decodes the message.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, TypeGuard, TypeVar, get_type_hints

import msgpack
from numpy.typing import NDArray

from agent.errors import MessageError
from agent.runtime.messages import arrays
from agent.runtime.messages.schema import (
    INT64_MAX,
    MAX_DEPTH,
    MAX_LIST_ITEMS,
    MAX_MAP_ITEMS,
    MAX_MESSAGE_BYTES,
    MAX_NAME_CHARS,
    MAX_STRING_CHARS,
    REGISTRY,
    Header,
    Message,
    Spec,
)

M = TypeVar("M", bound=Message)


@dataclass(frozen=True)
class FieldPlan:
    """One field of a message type: its name, its spec, and whether the wire must carry it."""

    name: str
    spec: Spec
    required: bool


_PLANS: dict[type[Message], tuple[FieldPlan, ...]] = {}


def field_plans(cls: type[Message]) -> tuple[FieldPlan, ...]:
    """How to encode and check each field of a message type (built once per type).

    Raises
    ------
    TypeError
        A field other than ``header`` was declared without a field specifier.
    """
    plan = _PLANS.get(cls)
    if plan is None:
        plan = _PLANS[cls] = _build_plans(cls)
    return plan


def _build_plans(cls: type[Message]) -> tuple[FieldPlan, ...]:
    hints = get_type_hints(cls)
    plans = []
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        declared = Spec("header") if f.name == "header" else f.metadata.get("spec")
        if not isinstance(declared, Spec):
            raise TypeError(f"{cls.__name__}.{f.name} ({hints.get(f.name)}) has no spec")
        spec = declared
        required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        plans.append(FieldPlan(f.name, spec, required and f.name != "header"))
    return tuple(plans)


def _pack_array(a: NDArray[Any], dtype: str) -> msgpack.ExtType:
    """An array as msgpack's extension value (for packing with msgpack directly)."""
    return msgpack.ExtType(arrays.ARRAY_EXT_CODE, arrays.pack(a, arrays.wire_dtype(dtype)))


def _ext_hook(code: int, data: bytes) -> Any:
    # Extension payloads are only kept here: _inspect refuses, naming where it is, any but a
    # well-formed typed array, and _check parses a known field's array and checks it.
    return _WireExt(code, data)


class _WireExt:
    """An extension value as received, before its field's validation."""

    __slots__ = ("code", "data")

    def __init__(self, code: int, data: bytes) -> None:
        self.code = code
        self.data = data


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
    except msgpack.StackError:  # msgpack's own limit, far beyond MAX_DEPTH
        raise MessageError(
            "oversized", f"maps and arrays nested deeper than {MAX_DEPTH} levels"
        ) from None
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
    """The type tag of an encoded message, validated only as far as needed.

    Raises
    ------
    MessageError
        The bytes are no msgpack map with a string ``type`` within the size limits.
    """
    obj = _unpack(data)
    if not isinstance(obj, dict) or not isinstance(obj.get("type"), str):
        raise MessageError("malformed", "not a map with a string 'type'")
    return str(obj["type"])


def decode(data: bytes, expect: type[M] | None = None) -> M | Message:
    """Decode and validate a message; raise :class:`MessageError` if it is unusable.

    With ``expect``, a message of another type is an error (kind ``unknown_type``). Arrays
    are read-only copies with memory of their own.
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
    _inspect(tag, obj, 1, ())
    values: dict[str, Any] = {}
    sizes: dict[str, int] = {}
    for plan in field_plans(cls):
        if plan.name not in obj:
            if plan.spec.kind == "header":
                raise MessageError("malformed", f"{tag}: missing header")
            if plan.required:
                raise MessageError("malformed", f"{tag}: missing field {plan.name!r}")
            continue
        values[plan.name] = _check(tag, plan, obj[plan.name], sizes)
    return cls(**values)


def _check(tag: str, plan: FieldPlan, raw: Any, sizes: dict[str, int]) -> Any:
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
        for key, number in (("stamp_ns", stamp), ("seq", seq)):
            if not 0 <= number <= INT64_MAX:
                raise MessageError(
                    "out_of_range", f"{tag}: header {key} = {number} outside [0, {INT64_MAX}]"
                )
        return Header(stamp_ns=stamp, seq=seq, frame_id=frame, source=source)
    if spec.kind == "array":
        if not isinstance(raw, _WireExt):
            raise MessageError("malformed", f"{where} must be a typed array")
        arr = arrays.parse(raw.code, raw.data, where)
        if arr.dtype != arrays.wire_dtype(spec.dtype):
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
            arrays.check_values(where, arr, spec)
        arr = arr.copy()  # aligned memory of its own, whatever the payload's offset
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
            isinstance(k, str) and _is_int(v) for k, v in raw.items()
        ):
            raise MessageError("malformed", f"{where} must map names to integer counts")
        if any(len(k) > MAX_NAME_CHARS for k in raw):
            raise MessageError("oversized", f"{where}: a name longer than {MAX_NAME_CHARS}")
        for k, v in raw.items():
            _range(f"{where}[{k!r}]", v, spec)
        return dict(raw)
    raise MessageError("malformed", f"{where}: unsupported field kind {spec.kind}")


# What msgpack decodes but extensions and maps and arrays: nothing inside to look at.
_PLAIN = frozenset({str, int, float, bool, bytes, type(None)})
_SHOWN_CHARS = 40  # of a map key, in a path naming where a problem is


def _path(tag: str, path: tuple[Any, ...]) -> str:
    """Where ``path`` (map keys and array indexes from the message's map) leads, for errors."""
    if not path:
        return tag
    return f"{tag}: field {_shown(path[0])}" + "".join(f"[{_shown(s)}]" for s in path[1:])


def _shown(step: Any) -> str:
    shown = repr(step)
    return shown if len(shown) <= _SHOWN_CHARS else shown[: _SHOWN_CHARS - 1] + "…"


def _inspect(tag: str, value: Any, depth: int, path: tuple[Any, ...]) -> None:
    """Refuse what no field may hold, wherever it is: an extension other than a well-formed
    typed array, and a map or array ``depth`` levels deep beyond :data:`MAX_DEPTH`.

    ``value`` is at ``path``, ``depth`` levels deep (the message's map is level 1). Only maps,
    arrays and extensions are looked into; a map or array of plain values is passed over in C.
    """
    cls = value.__class__
    if cls is dict or cls is list:
        if depth > MAX_DEPTH:  # named by its field: the whole path would be a long line
            raise MessageError(
                "oversized",
                f"{_path(tag, path[:1])}: maps and arrays nested deeper than {MAX_DEPTH} levels",
            )
        inside = value.values() if cls is dict else value
        if _PLAIN.issuperset(map(type, inside)):
            return
        for key, item in value.items() if cls is dict else enumerate(value):
            if item.__class__ not in _PLAIN:
                _inspect(tag, item, depth + 1, (*path, key))
    elif cls is _WireExt:
        arrays.parse(value.code, value.data, _path(tag, path))  # well-formed, or refused
    elif cls is msgpack.Timestamp:  # extension type -1, which msgpack decodes itself
        raise MessageError(
            "malformed",
            f"{_path(tag, path)}: msgpack extension type -1 (a timestamp), not a typed array",
        )


def _is_int(value: Any) -> TypeGuard[int]:
    return isinstance(value, int) and not isinstance(value, bool)


def _range(where: str, value: float, spec: Spec) -> None:
    if (spec.lo is not None and value < spec.lo) or (spec.hi is not None and value > spec.hi):
        raise MessageError("out_of_range", f"{where} = {value} outside [{spec.lo}, {spec.hi}]")
