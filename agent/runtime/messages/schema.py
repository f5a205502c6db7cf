"""How a message type is declared: field specifiers, the header, the base class, the registry.

A message type is a frozen, keyword-only dataclass deriving from :class:`Message`, registered
under its type tag by :func:`message`; each field other than ``header`` is declared with one
of the specifiers below (:func:`f64`, :func:`i64`, :func:`boolean`, :func:`text`,
:func:`array`, :func:`counters`), which attach a :class:`Spec` saying what the field may
hold. The codec reads the specs; nothing else describes the wire.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar, TypeVar

import numpy as np

# The codec builds on this module, so Message.to_wire reaches it through the package, once
# both are loaded.
import agent.runtime.messages as _package

MAX_MESSAGE_BYTES = 8 * 1024 * 1024
MAX_ARRAY_ELEMENTS = 1 << 20
MAX_STRING_CHARS = 4096
MAX_DIMENSIONS = 4
MAX_LIST_ITEMS = 4096
MAX_MAP_ITEMS = 256
MAX_NAME_CHARS = 256  # type tags, header frame ids and sources, counter names
MAX_DEPTH = 32  # levels of maps and arrays, the message's own map the first
# Every integer the agent reads (header stamp_ns and seq, int fields, counter values) is an
# int64: msgpack's uint64 above INT64_MAX is out of range.
INT64_MIN = -(1 << 63)
INT64_MAX = (1 << 63) - 1


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
    """An integer field: an int64, within ``lo`` … ``hi`` where given (inclusive)."""
    lo = INT64_MIN if lo is None else max(lo, INT64_MIN)
    hi = INT64_MAX if hi is None else min(hi, INT64_MAX)
    spec = Spec("int", "", lo, hi, doc=doc)
    if default is None:
        return field(metadata=_meta(spec))
    return field(default=default, metadata=_meta(spec))


def boolean(default: bool | None = None, doc: str = "") -> Any:
    """A boolean field."""
    spec = Spec("bool", doc=doc)
    if default is None:
        return field(metadata=_meta(spec))
    return field(default=default, metadata=_meta(spec))


def text(default: str | None = None, choices: tuple[str, ...] = (), doc: str = "") -> Any:
    """A string field, free or one of ``choices``."""
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
    """A map of counter names to counts: int64 values of 0 … ``INT64_MAX``."""
    spec = Spec("dict", lo=0, hi=INT64_MAX, doc=doc)
    return field(default_factory=dict, metadata=_meta(spec))


# --------------------------------------------------------------------------------- header
@dataclass(frozen=True)
class Header:
    """Every message's header.

    stamp_ns : time the message's content refers to, integer nanoseconds on the graph's clock
        (0 … ``INT64_MAX`` on the wire).
    seq : per-publisher, per-topic sequence number, gaps show drops (0 … ``INT64_MAX``).
    frame_id : the frame the content is expressed in.
    source : name of the process that produced it.
    """

    stamp_ns: int = 0
    seq: int = 0
    frame_id: str = ""
    source: str = ""

    @property
    def stamp_s(self) -> float:
        """``stamp_ns`` in seconds."""
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
        """The type tag, ``TYPE/VERSION``."""
        return f"{self.TYPE}/{self.VERSION}"

    def to_wire(
        self, *, seq: int | None = None, source: str | None = None, stamp_ns: int | None = None
    ) -> bytes:
        """Encode as msgpack bytes, with the header's ``seq``, ``source`` or ``stamp_ns``
        replaced where given (a publisher's stamping, without copying the message)."""
        return _package.encode(self, seq=seq, source=source, stamp_ns=stamp_ns)

    def with_header(self: M, **changes: Any) -> M:
        """A copy with header fields replaced (``seq``, ``source``, ...)."""
        header = self.header
        fields: dict[str, Any] = {
            "stamp_ns": header.stamp_ns, "seq": header.seq, "frame_id": header.frame_id,
            "source": header.source, **changes,
        }  # fmt: skip
        # A shallow copy with the new header: the body was validated when it was made (a
        # ``dataclasses.replace`` would build and check it again, for every message the
        # lock-step runner passes on).
        copy = object.__new__(type(self))
        copy.__dict__.update(self.__dict__)
        object.__setattr__(copy, "header", Header(**fields))
        return copy


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


def message_types() -> Mapping[str, type[Message]]:
    """Every registered message type, by tag."""
    return dict(REGISTRY)
