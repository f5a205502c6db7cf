"""Typed arrays on the wire: msgpack extension type 1.

The extension's payload is one dtype byte (``d`` float64, ``f`` float32, ``q`` int64, ``i``
int32, ``B`` uint8, ``?`` bool), one byte for the number of dimensions, each dimension as a
little-endian uint32, then the little-endian data in C order.
"""

from __future__ import annotations

import functools
import math
import struct
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agent.errors import MessageError
from agent.runtime.messages.schema import MAX_ARRAY_ELEMENTS, MAX_DIMENSIONS, Spec

ARRAY_EXT_CODE = 1

DTYPES: dict[bytes, np.dtype[Any]] = {
    b"d": np.dtype("<f8"), b"f": np.dtype("<f4"), b"q": np.dtype("<i8"),
    b"i": np.dtype("<i4"), b"B": np.dtype("u1"), b"?": np.dtype("?"),
}  # fmt: skip
CODES = {dt: code for code, dt in DTYPES.items()}

# The dimensions of an array of 0 ... MAX_DIMENSIONS dimensions, as packed in its payload.
_SHAPES = tuple(struct.Struct(f"<{ndim}I") for ndim in range(MAX_DIMENSIONS + 1))


@functools.cache
def wire_dtype(dtype: str) -> np.dtype[Any]:
    """The dtype on the wire of a field declared as ``dtype`` (``f8`` → little-endian ``<f8``)."""
    dt = np.dtype(dtype)
    return dt.newbyteorder("<") if dt.itemsize > 1 else dt


def payload_head(dt: np.dtype[Any], shape: tuple[int, ...]) -> bytes:
    """The payload's bytes before the data: dtype code, dimension count and dimensions."""
    return CODES[dt] + bytes((len(shape),)) + struct.pack(f"<{len(shape)}I", *shape)


def pack(a: Any, dt: np.dtype[Any]) -> bytes:
    """The extension payload of an array (anything ``numpy.asarray`` takes) as dtype ``dt``.

    ``dt`` is a wire dtype (see :func:`wire_dtype`); values are converted to it.
    """
    arr = np.ascontiguousarray(a, dtype=dt)
    return b"".join((payload_head(dt, arr.shape), arr))  # type: ignore[arg-type]  # a buffer


# msgpack frames an extension payload in its shortest form, as encoders write it: fixext for
# 1, 2, 4, 8 and 16 bytes, else ext 8, 16 or 32.
_FIXEXT = {1: 0xD4, 2: 0xD5, 4: 0xD6, 8: 0xD7, 16: 0xD8}
# The length of an extension's framing, up to its payload, by its first byte.
FRAMING_LENGTH = {**dict.fromkeys(_FIXEXT.values(), 2), 0xC7: 3, 0xC8: 4, 0xC9: 6}


def ext_start(dt: np.dtype[Any], shape: tuple[int, ...]) -> bytes:
    """The msgpack bytes of an array of ``dt`` and ``shape`` before its data: the extension's
    framing (shortest form), its type and the payload head."""
    head = payload_head(dt, shape)
    length = len(head) + math.prod(shape) * dt.itemsize
    code = bytes((ARRAY_EXT_CODE,))
    if length in _FIXEXT:
        framing = bytes((_FIXEXT[length],)) + code
    elif length < 1 << 8:
        framing = bytes((0xC7, length)) + code
    elif length < 1 << 16:
        framing = b"\xc8" + length.to_bytes(2, "big") + code
    else:
        framing = b"\xc9" + length.to_bytes(4, "big") + code
    return framing + head


def parse(code: int, data: bytes, where: str) -> NDArray[Any]:
    """The array an extension holds, as a read-only view of ``data``.

    Raises
    ------
    MessageError
        ``malformed`` for another extension type, an unknown dtype code, too many dimensions
        or data longer than the shape says; ``truncated`` when the header or data is cut
        short; ``oversized`` beyond :data:`MAX_ARRAY_ELEMENTS`. ``where`` starts the message.
    """
    if code != ARRAY_EXT_CODE:
        raise MessageError("malformed", f"{where}: unknown msgpack extension type {code}")
    if len(data) < 2:
        raise MessageError("truncated", f"{where}: array header cut short")
    dtype = DTYPES.get(data[:1])
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
    shape = _SHAPES[ndim].unpack_from(data, 2)
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


def check_values(where: str, arr: NDArray[Any], spec: Spec) -> None:
    """Refuse a non-empty array holding inf (or NaN, unless allowed) or values out of range.

    Two reductions, the least and the greatest value, answer every check: ``fmin``/``fmax``
    skip NaN where it is allowed (it marks "no value"), ``min``/``max`` carry it where it is
    not.

    Raises
    ------
    MessageError
        ``out_of_range``, naming ``where``.
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
