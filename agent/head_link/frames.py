"""Framing of the head's serial protocol (``docs/head-protocol.md`` §2): COBS, a length, a
sequence number, a type and a CRC-32, one zero byte between frames.

A frame before stuffing::

    type u8 | seq u16 | length u16 | body (length bytes) | crc32 u32      (little-endian)

The CRC (IEEE 802.3, :func:`zlib.crc32`) covers everything before it. The whole is
COBS-encoded (the ``cobs`` package: no zero byte inside) and followed by ``0x00``. A
receiver that loses or gains a byte, or sees garbage, loses at most the frame it happens in:
the next ``0x00`` ends it, and the one after is whole again. Everything that is dropped is
counted (:class:`FrameCounters`), never raised: a serial line is noisy by nature.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field, fields

from cobs import cobs

__all__ = [
    "HEADER",
    "MAX_BODY",
    "MAX_ENCODED",
    "Frame",
    "FrameCounters",
    "FrameDecoder",
    "encode_frame",
]

HEADER = struct.Struct("<BHH")  # type, seq, body length
_CRC = struct.Struct("<I")
MAX_BODY = 1024
"""The longest body a frame may carry (a samples frame of 32 is 458 bytes)."""
MAX_ENCODED = HEADER.size + MAX_BODY + _CRC.size + (HEADER.size + MAX_BODY + _CRC.size) // 254 + 1
"""The longest a frame can be on the wire, stuffed, without its delimiter: a receiver that
has gathered more than this without a ``0x00`` is reading garbage and drops it."""


@dataclass(frozen=True)
class Frame:
    """One frame: its ``type`` (:mod:`agent.head_link.messages`), sequence number (the
    sender's, one per frame, wrapping at 2¹⁶) and ``body``."""

    type: int
    seq: int
    body: bytes


def encode_frame(kind: int, seq: int, body: bytes) -> bytes:
    """The bytes to write for one frame, delimiter included.

    Raises
    ------
    ValueError
        For a type outside 0-255, a sequence number outside 0-65535 or a body longer than
        :data:`MAX_BODY`.
    """
    if not 0 <= kind <= 0xFF:
        raise ValueError(f"frame type must be 0-255, got {kind}")
    if not 0 <= seq <= 0xFFFF:
        raise ValueError(f"frame sequence number must be 0-65535, got {seq}")
    if len(body) > MAX_BODY:
        raise ValueError(f"frame body of {len(body)} bytes is longer than {MAX_BODY}")
    raw = HEADER.pack(kind, seq, len(body)) + body
    raw += _CRC.pack(zlib.crc32(raw))
    return bytes(cobs.encode(raw)) + b"\x00"


@dataclass
class FrameCounters:
    """What a :class:`FrameDecoder` took and dropped (each a count).

    ``frames`` good frames; ``bytes`` bytes fed; ``discarded_bytes`` bytes of dropped
    frames and garbage; ``cobs_errors`` chunks that were not valid COBS; ``short`` chunks
    too short for a header and CRC; ``crc_errors`` CRC mismatches; ``length_errors`` a
    length field that disagrees with the frame; ``oversize`` runs longer than
    :data:`MAX_ENCODED` with no delimiter (dropped as they went); ``seq_gaps`` frames missing
    between two good ones, by their sequence numbers; ``seq_backwards`` good frames whose
    number is not after the last (a sender that restarted).
    """

    frames: int = 0
    bytes: int = 0
    discarded_bytes: int = 0
    cobs_errors: int = 0
    short: int = 0
    crc_errors: int = 0
    length_errors: int = 0
    oversize: int = 0
    seq_gaps: int = 0
    seq_backwards: int = 0

    def as_dict(self) -> dict[str, int]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @property
    def dropped(self) -> int:
        """Chunks dropped for any reason."""
        return self.cobs_errors + self.short + self.crc_errors + self.length_errors + self.oversize


@dataclass
class FrameDecoder:
    """Cuts a byte stream into frames (module docstring). Feed it whatever the port gives;
    it keeps a partial frame between calls."""

    counters: FrameCounters = field(default_factory=FrameCounters)
    _buffer: bytearray = field(default_factory=bytearray)
    _last_seq: int | None = None
    _skipping: bool = False

    def feed(self, data: bytes) -> list[Frame]:
        """The frames completed by ``data``, in order."""
        c = self.counters
        c.bytes += len(data)
        out: list[Frame] = []
        chunks = data.split(b"\x00")
        for i, chunk in enumerate(chunks):
            last = i == len(chunks) - 1
            if self._skipping:  # an oversize run: drop up to its delimiter
                c.discarded_bytes += len(chunk)
                if not last:
                    self._skipping = False
                continue
            self._buffer += chunk
            if last:  # no delimiter yet: wait for more, unless it cannot be a frame
                if len(self._buffer) > MAX_ENCODED:
                    c.oversize += 1
                    c.discarded_bytes += len(self._buffer)
                    self._buffer.clear()
                    self._skipping = True
                break
            frame = self._cut(bytes(self._buffer))
            self._buffer.clear()
            if frame is not None:
                out.append(frame)
        return out

    def _cut(self, chunk: bytes) -> Frame | None:
        c = self.counters
        if not chunk:  # idle delimiters between frames
            return None
        if len(chunk) > MAX_ENCODED:
            c.oversize += 1
            c.discarded_bytes += len(chunk)
            return None
        try:
            raw = cobs.decode(chunk)
        except cobs.DecodeError:
            c.cobs_errors += 1
            c.discarded_bytes += len(chunk)
            return None
        if len(raw) < HEADER.size + _CRC.size:
            c.short += 1
            c.discarded_bytes += len(chunk)
            return None
        (crc,) = _CRC.unpack_from(raw, len(raw) - _CRC.size)
        if zlib.crc32(raw[: -_CRC.size]) != crc:
            c.crc_errors += 1
            c.discarded_bytes += len(chunk)
            return None
        kind, seq, length = HEADER.unpack_from(raw)
        if length != len(raw) - HEADER.size - _CRC.size:
            c.length_errors += 1
            c.discarded_bytes += len(chunk)
            return None
        if self._last_seq is not None:
            gap = (seq - self._last_seq - 1) % 0x10000
            if gap < 0x8000:
                c.seq_gaps += gap
            else:  # a repeat or an older frame (the sender restarted, or a replay)
                c.seq_backwards += 1
        self._last_seq = seq
        c.frames += 1
        return Frame(kind, seq, raw[HEADER.size : -_CRC.size])
