"""The bodies of the head's serial protocol (``docs/head-protocol.md`` §3), version 1.

Each message is a frozen dataclass with its frame ``TYPE``, :meth:`pack` (to a body) and
``unpack`` (from one, checking its length and values); :func:`decode` reads any frame's.
A body that is malformed raises :class:`ProtocolError` with one line naming the message
and what was wrong; the link counts it and goes on.

Units on the wire are integers where a fixed step serves (angles in µrad or in the
samples' steps, times in µs) and IEEE floats where the range is wide (photocurrents).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass, fields
from enum import IntEnum
from typing import ClassVar, Protocol, Self

import numpy as np

from agent.arrays import FloatArray
from agent.head_link.frames import MAX_BODY, Frame

__all__ = [
    "PROTOCOL_VERSION",
    "SAMPLE_DTYPE",
    "Ack",
    "Heartbeat",
    "Hello",
    "HelloReply",
    "Laser",
    "Message",
    "Nak",
    "Pan",
    "ProtocolError",
    "Rearm",
    "Reason",
    "SafetyState",
    "Samples",
    "Status",
    "StatusRequest",
    "TimeReply",
    "TimeRequest",
    "Window",
    "decode",
]

PROTOCOL_VERSION = 1
URAD = 1e-6
SCAN_STEP_RAD = 2e-5  # a sample's scan angle: i16 steps of 20 µrad, ±0.655 rad
PAN_STEP_RAD = 5e-5  # a sample's pan: i16 steps of 50 µrad, ±1.638 rad
MAX_SAMPLES = (MAX_BODY - 10) // 14
_TEXT = 16  # firmware, serial number and calibration id: ASCII, NUL padded
_REASON_TEXT = 48

SAMPLE_DTYPE = np.dtype(
    [("dt_us", "<u2"), ("scan", "<i2"), ("pan", "<i2"), ("i1_A", "<f4"), ("i2_A", "<f4")]
)
"""One sample on the wire (14 bytes): µs after the frame's first sample, scan angle and pan
in their steps, the two electrode currents (A)."""


class ProtocolError(ValueError):
    """A body the protocol does not allow (one line: which message, what is wrong)."""


class Reason(IntEnum):
    """Why the head refused a command (:class:`Nak`)."""

    MALFORMED = 1  # the body did not parse
    OUT_OF_RANGE = 2  # a pan or window outside what the head can do
    LASER_LOCKED = 3  # laser on asked while tripped: re-arm first
    UNKNOWN_TYPE = 4  # a frame type it does not know
    NOT_READY = 5  # before the handshake, or while the mirror spins up


class SafetyState(IntEnum):
    """The laser's safety state machine (``docs/head-protocol.md`` §5)."""

    OFF = 0  # laser off, nothing wrong: may be switched on
    ON = 1  # laser on, mirror at speed, heartbeat fresh
    TRIPPED = 2  # switched off by a fault; stays off until re-armed


class Message(Protocol):
    TYPE: ClassVar[int]

    def pack(self) -> bytes: ...


def _exact(name: str, body: bytes, size: int) -> None:
    if len(body) != size:
        raise ProtocolError(f"{name}: body of {len(body)} bytes, expected {size}")


def _text(name: str, what: str, value: str, size: int) -> bytes:
    raw = value.encode("ascii", errors="strict") if value.isascii() else b""
    if not value.isascii() or len(raw) > size or "\x00" in value:
        raise ProtocolError(f"{name}: {what} must be ASCII of at most {size} bytes, no NUL")
    return raw.ljust(size, b"\x00")


def _untext(name: str, what: str, raw: bytes) -> str:
    text = raw.rstrip(b"\x00")
    if b"\x00" in text or not text.isascii():
        raise ProtocolError(f"{name}: {what} is not NUL-padded ASCII")
    return text.decode("ascii")


def _angle_urad(name: str, what: str, value_rad: float) -> int:
    if not math.isfinite(value_rad) or abs(value_rad) > 2.0 * math.pi:
        raise ProtocolError(f"{name}: {what} {value_rad!r} rad is not a finite angle")
    return round(value_rad / URAD)


class _Plain:
    """A body of integer fields packed in their order by ``_S`` (the simple messages);
    ``NAME`` for errors."""

    NAME: ClassVar[str]
    _S: ClassVar[struct.Struct]

    def pack(self) -> bytes:
        values = [getattr(self, f.name) for f in fields(self)]  # type: ignore[arg-type]
        try:
            return self._S.pack(*values)
        except struct.error as exc:  # a value beyond its field's width
            raise ProtocolError(f"{self.NAME}: {exc}") from None

    @classmethod
    def unpack(cls, body: bytes) -> Self:
        _exact(cls.NAME, body, cls._S.size)
        return cls(*cls._S.unpack(body))


@dataclass(frozen=True)
class Hello(_Plain):
    """Host → head, first: the protocol version the host speaks."""

    TYPE: ClassVar[int] = 0x01
    NAME: ClassVar[str] = "hello"
    _S: ClassVar[struct.Struct] = struct.Struct("<H")
    protocol_version: int = PROTOCOL_VERSION


@dataclass(frozen=True)
class HelloReply:
    """Head → host: who it is. ``protocol_version`` the head's (the host refuses another)."""

    TYPE: ClassVar[int] = 0x02
    _S: ClassVar[struct.Struct] = struct.Struct(f"<H{_TEXT}s{_TEXT}s{_TEXT}s")
    protocol_version: int
    firmware: str
    serial_number: str
    calibration_id: str

    def pack(self) -> bytes:
        return self._S.pack(
            self.protocol_version,
            _text("hello_reply", "firmware", self.firmware, _TEXT),
            _text("hello_reply", "serial_number", self.serial_number, _TEXT),
            _text("hello_reply", "calibration_id", self.calibration_id, _TEXT),
        )

    @classmethod
    def unpack(cls, body: bytes) -> HelloReply:
        _exact("hello_reply", body, cls._S.size)
        version, fw, sn, cal = cls._S.unpack(body)
        return cls(
            version,
            _untext("hello_reply", "firmware", fw),
            _untext("hello_reply", "serial_number", sn),
            _untext("hello_reply", "calibration_id", cal),
        )


@dataclass(frozen=True)
class Pan:
    """Host → head: slew the pan axis to ``target_rad``."""

    TYPE: ClassVar[int] = 0x10
    _S: ClassVar[struct.Struct] = struct.Struct("<i")
    target_rad: float

    def pack(self) -> bytes:
        return self._S.pack(_angle_urad("pan", "target", self.target_rad))

    @classmethod
    def unpack(cls, body: bytes) -> Pan:
        _exact("pan", body, cls._S.size)
        return cls(cls._S.unpack(body)[0] * URAD)


@dataclass(frozen=True)
class Window:
    """Host → head: scan the mirror between ``low_rad`` and ``high_rad``."""

    TYPE: ClassVar[int] = 0x11
    _S: ClassVar[struct.Struct] = struct.Struct("<ii")
    low_rad: float
    high_rad: float

    def pack(self) -> bytes:
        return self._S.pack(
            _angle_urad("window", "low", self.low_rad),
            _angle_urad("window", "high", self.high_rad),
        )

    @classmethod
    def unpack(cls, body: bytes) -> Window:
        _exact("window", body, cls._S.size)
        low, high = cls._S.unpack(body)
        return cls(low * URAD, high * URAD)


@dataclass(frozen=True)
class Laser:
    """Host → head: laser on (1) or off (0)."""

    TYPE: ClassVar[int] = 0x12
    _S: ClassVar[struct.Struct] = struct.Struct("<B")
    on: bool

    def pack(self) -> bytes:
        return self._S.pack(int(self.on))

    @classmethod
    def unpack(cls, body: bytes) -> Laser:
        _exact("laser", body, cls._S.size)
        (on,) = cls._S.unpack(body)
        if on > 1:
            raise ProtocolError(f"laser: on must be 0 or 1, got {on}")
        return cls(bool(on))


@dataclass(frozen=True)
class Rearm(_Plain):
    """Host → head: leave ``TRIPPED`` for ``OFF`` (the fault must be gone)."""

    TYPE: ClassVar[int] = 0x13
    NAME: ClassVar[str] = "rearm"
    _S: ClassVar[struct.Struct] = struct.Struct("<")


@dataclass(frozen=True)
class Heartbeat(_Plain):
    """Host → head: the host is alive (its clock, µs)."""

    TYPE: ClassVar[int] = 0x14
    NAME: ClassVar[str] = "heartbeat"
    _S: ClassVar[struct.Struct] = struct.Struct("<Q")
    host_time_us: int


@dataclass(frozen=True)
class StatusRequest(_Plain):
    """Host → head: send a :class:`Status` now."""

    TYPE: ClassVar[int] = 0x15
    NAME: ClassVar[str] = "status_request"
    _S: ClassVar[struct.Struct] = struct.Struct("<")


@dataclass(frozen=True)
class TimeRequest(_Plain):
    """Host → head: a clock probe, stamped with the host's send time (µs)."""

    TYPE: ClassVar[int] = 0x16
    NAME: ClassVar[str] = "time_request"
    _S: ClassVar[struct.Struct] = struct.Struct("<Q")
    host_time_us: int


@dataclass(frozen=True)
class Ack(_Plain):
    """Head → host: the command ``seq`` of type ``command_type`` is done (or under way)."""

    TYPE: ClassVar[int] = 0x20
    NAME: ClassVar[str] = "ack"
    _S: ClassVar[struct.Struct] = struct.Struct("<HB")
    seq: int
    command_type: int


@dataclass(frozen=True)
class Nak:
    """Head → host: the command ``seq`` is refused, with a :class:`Reason` and a line."""

    TYPE: ClassVar[int] = 0x21
    _S: ClassVar[struct.Struct] = struct.Struct(f"<HBB{_REASON_TEXT}s")
    seq: int
    command_type: int
    reason: Reason
    text: str = ""

    def pack(self) -> bytes:
        text = self.text[:_REASON_TEXT] if self.text.isascii() else "?"
        return self._S.pack(
            self.seq, self.command_type, int(self.reason),
            _text("nak", "text", text.replace("\x00", " "), _REASON_TEXT),
        )  # fmt: skip

    @classmethod
    def unpack(cls, body: bytes) -> Nak:
        _exact("nak", body, cls._S.size)
        seq, kind, reason, text = cls._S.unpack(body)
        try:
            why = Reason(reason)
        except ValueError:
            raise ProtocolError(f"nak: unknown reason {reason}") from None
        return cls(seq, kind, why, _untext("nak", "text", text))


@dataclass(frozen=True)
class Status:
    """Head → host, at 10 Hz and on request: the head's state and its own counters."""

    TYPE: ClassVar[int] = 0x30
    _S: ClassVar[struct.Struct] = struct.Struct("<QBBfiiiiIIII")
    head_time_us: int
    state: SafetyState
    laser_on: bool
    mirror_rate_rad_s: float
    pan_rad: float
    pan_target_rad: float
    window_low_rad: float
    window_high_rad: float
    frames_received: int
    crc_errors: int
    commands_refused: int
    trips: int

    def pack(self) -> bytes:
        return self._S.pack(
            self.head_time_us, int(self.state), int(self.laser_on), self.mirror_rate_rad_s,
            _angle_urad("status", "pan", self.pan_rad),
            _angle_urad("status", "pan_target", self.pan_target_rad),
            _angle_urad("status", "window_low", self.window_low_rad),
            _angle_urad("status", "window_high", self.window_high_rad),
            self.frames_received, self.crc_errors, self.commands_refused, self.trips,
        )  # fmt: skip

    @classmethod
    def unpack(cls, body: bytes) -> Status:
        _exact("status", body, cls._S.size)
        t, state, laser, rate, pan, target, low, high, rx, crc, refused, trips = cls._S.unpack(body)
        try:
            safety = SafetyState(state)
        except ValueError:
            raise ProtocolError(f"status: unknown safety state {state}") from None
        if laser > 1 or not math.isfinite(rate):
            raise ProtocolError(f"status: laser {laser} or mirror rate {rate} out of range")
        return cls(
            t, safety, bool(laser), rate, pan * URAD, target * URAD, low * URAD, high * URAD,
            rx, crc, refused, trips,
        )  # fmt: skip


@dataclass(frozen=True)
class TimeReply(_Plain):
    """Head → host: the probe's host stamp echoed, and the head's clock when it came (µs)."""

    TYPE: ClassVar[int] = 0x31
    NAME: ClassVar[str] = "time_reply"
    _S: ClassVar[struct.Struct] = struct.Struct("<QQ")
    host_time_us: int
    head_time_us: int


@dataclass(frozen=True, eq=False)
class Samples:
    """Head → host: consecutive samples (at most :data:`MAX_SAMPLES`), the first at
    ``head_time_us``; each sample's time, scan angle (rad), pan (rad) and the two electrode
    currents (A), quantised on the wire (:data:`SAMPLE_DTYPE`)."""

    TYPE: ClassVar[int] = 0x40
    _S: ClassVar[struct.Struct] = struct.Struct("<QH")
    head_time_us: int
    time_us: FloatArray  # (n,) head µs of each sample
    scan_rad: FloatArray
    pan_rad: FloatArray
    i1_A: FloatArray
    i2_A: FloatArray

    @classmethod
    def of(
        cls,
        time_us: FloatArray,
        scan_rad: FloatArray,
        pan_rad: FloatArray,
        i1_A: FloatArray,
        i2_A: FloatArray,
    ) -> Samples:
        """Samples as they will read back: quantised to the wire's steps."""
        return cls.unpack(cls._pack(time_us, scan_rad, pan_rad, i1_A, i2_A))

    @classmethod
    def _pack(
        cls,
        time_us: FloatArray,
        scan_rad: FloatArray,
        pan_rad: FloatArray,
        i1_A: FloatArray,
        i2_A: FloatArray,
    ) -> bytes:
        t = np.asarray(time_us, dtype=np.float64)
        n = t.size
        if not 1 <= n <= MAX_SAMPLES:
            raise ProtocolError(f"samples: {n} samples, expected 1-{MAX_SAMPLES}")
        arrays = [np.asarray(a, dtype=np.float64) for a in (scan_rad, pan_rad, i1_A, i2_A)]
        if any(a.shape != t.shape for a in arrays) or not all(
            np.all(np.isfinite(a)) for a in [t, *arrays]
        ):
            raise ProtocolError("samples: arrays of unequal length or not finite")
        first = round(float(t[0]))
        dt = np.rint(t - first)
        scan = np.rint(arrays[0] / SCAN_STEP_RAD)
        pan = np.rint(arrays[1] / PAN_STEP_RAD)
        if first < 0 or dt.min() < 0 or dt.max() > 0xFFFF:
            raise ProtocolError("samples: times must rise from the first within 65.5 ms")
        if np.abs(scan).max() > 0x7FFF or np.abs(pan).max() > 0x7FFF:
            raise ProtocolError("samples: scan angle beyond ±0.655 rad or pan beyond ±1.638 rad")
        rec = np.empty(n, dtype=SAMPLE_DTYPE)
        rec["dt_us"], rec["scan"], rec["pan"] = dt, scan, pan
        rec["i1_A"], rec["i2_A"] = arrays[2], arrays[3]
        return cls._S.pack(first, n) + rec.tobytes()

    def pack(self) -> bytes:
        return self._pack(self.time_us, self.scan_rad, self.pan_rad, self.i1_A, self.i2_A)

    @classmethod
    def unpack(cls, body: bytes) -> Samples:
        if len(body) < cls._S.size:
            raise ProtocolError(f"samples: body of {len(body)} bytes has no header")
        first, n = cls._S.unpack_from(body)
        if not 1 <= n <= MAX_SAMPLES or len(body) != cls._S.size + n * SAMPLE_DTYPE.itemsize:
            raise ProtocolError(f"samples: {len(body)} bytes do not hold the {n} samples it says")
        rec = np.frombuffer(body, dtype=SAMPLE_DTYPE, offset=cls._S.size, count=n)
        i1 = rec["i1_A"].astype(np.float64)
        i2 = rec["i2_A"].astype(np.float64)
        if not (np.all(np.isfinite(i1)) and np.all(np.isfinite(i2))):
            raise ProtocolError("samples: a current is not finite")
        return cls(
            first, first + rec["dt_us"].astype(np.float64), rec["scan"] * SCAN_STEP_RAD,
            rec["pan"] * PAN_STEP_RAD, i1, i2,
        )  # fmt: skip


_UNPACK: dict[int, Callable[[bytes], Message]] = {
    cls.TYPE: cls.unpack
    for cls in (
        Hello, HelloReply, Pan, Window, Laser, Rearm, Heartbeat, StatusRequest, TimeRequest,
        Ack, Nak, Status, TimeReply, Samples,
    )
}  # fmt: skip


def decode(frame: Frame) -> Message:
    """The message a frame carries.

    Raises
    ------
    ProtocolError
        For a type the protocol does not have, or a malformed body (one line).
    """
    unpack = _UNPACK.get(frame.type)
    if unpack is None:
        raise ProtocolError(f"frame type 0x{frame.type:02x} is not in protocol version 1")
    return unpack(frame.body)
