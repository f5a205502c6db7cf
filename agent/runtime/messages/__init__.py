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
shape (arrays sharing a dimension name, such as ``n`` samples, must agree) and range. Every
integer read is an int64 (``stamp_ns``, ``seq``, int fields, counter values); anywhere in a
message, fields it does not know included, no extension other than a well-formed typed array
and no nesting of maps and arrays deeper than :data:`MAX_DEPTH` levels is taken. Any failure
raises :class:`agent.errors.MessageError` with a ``kind`` for counting.

Modules
-------
* :mod:`.schema`: how a message type is declared (field specs, header, base class, registry).
* :mod:`.types`: the message types.
* :mod:`.arrays`: the typed-array extension.
* :mod:`.codec`: :func:`encode` and :func:`decode`, in msgspec's compiled code.
* :mod:`.reading`: what :func:`decode` checks after msgspec: the header and the arrays.
* :mod:`.checks`: the reference decoder, which names every failure :func:`decode` refuses.
"""

from agent.runtime.messages.arrays import ARRAY_EXT_CODE
from agent.runtime.messages.checks import _pack_array
from agent.runtime.messages.codec import decode, encode, peek_type
from agent.runtime.messages.schema import (
    INT64_MAX,
    INT64_MIN,
    MAX_ARRAY_ELEMENTS,
    MAX_DEPTH,
    MAX_DIMENSIONS,
    MAX_LIST_ITEMS,
    MAX_MAP_ITEMS,
    MAX_MESSAGE_BYTES,
    MAX_NAME_CHARS,
    MAX_STRING_CHARS,
    REGISTRY,
    Header,
    Message,
    Spec,
    array,
    boolean,
    counters,
    f64,
    i64,
    message,
    message_types,
    stamp_ns,
    text,
)
from agent.runtime.messages.types import (
    PI,
    CalibratedScan,
    EnvironmentVector,
    Features,
    FilteredScan,
    FloatArray,
    HeadCommand,
    HeadState,
    Heartbeat,
    Odometry,
    RawScan,
    Stop,
    Tracks,
    VehicleState,
    WheelCommand,
    WorldTruth,
)

__all__ = [
    "ARRAY_EXT_CODE",
    "INT64_MAX",
    "INT64_MIN",
    "MAX_ARRAY_ELEMENTS",
    "MAX_DEPTH",
    "MAX_DIMENSIONS",
    "MAX_LIST_ITEMS",
    "MAX_MAP_ITEMS",
    "MAX_MESSAGE_BYTES",
    "MAX_NAME_CHARS",
    "MAX_STRING_CHARS",
    "PI",
    "REGISTRY",
    "CalibratedScan",
    "EnvironmentVector",
    "Features",
    "FilteredScan",
    "FloatArray",
    "HeadCommand",
    "HeadState",
    "Header",
    "Heartbeat",
    "Message",
    "Odometry",
    "RawScan",
    "Spec",
    "Stop",
    "Tracks",
    "VehicleState",
    "WheelCommand",
    "WorldTruth",
    "_pack_array",
    "array",
    "boolean",
    "counters",
    "decode",
    "encode",
    "f64",
    "i64",
    "message",
    "message_types",
    "peek_type",
    "stamp_ns",
    "text",
]
