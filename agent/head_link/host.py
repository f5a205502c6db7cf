"""The host's end of the head's serial link (``docs/head-protocol.md`` §4), without the port:
bytes in, bytes out, on a clock it is given.

:class:`HeadLink` greets the head until it answers (and refuses another protocol version),
sends the head's commands when they change, a heartbeat every 0.1 s and a clock probe every
second, keeps the head's latest status, and cuts the samples into sweeps
(:class:`agent.sensor.samples.RawScan`: a run of samples in one direction, ended by the
mirror's reversal or by a gap), stamped on the
host's clock through :class:`~agent.head_link.clock.ClockAlignment`. Everything it drops is
counted (:attr:`HeadLink.counters`). The ``head`` process's serial backend gives it the
port's bytes; tests give it an emulated head's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from agent.arrays import FloatArray
from agent.head_link import messages as m
from agent.head_link.clock import ClockAlignment
from agent.head_link.frames import FrameDecoder, encode_frame
from agent.sensor.samples import RawScan

__all__ = ["HeadLink"]

HELLO_RETRY_S = 0.5
HEARTBEAT_S = 0.1
TIME_PROBE_S = 1.0
SWEEP_GAP_S = 0.002  # samples further apart than this (a lost frame, the laser off) end a sweep
STREAM_TIMEOUT_S = 0.2  # no sample for this long: the head is not streaming


@dataclass
class HeadLink:
    """The host's protocol logic (module docstring); times in seconds on the host's clock."""

    decoder: FrameDecoder = field(default_factory=FrameDecoder)
    clock: ClockAlignment = field(default_factory=ClockAlignment)
    identity: m.HelloReply | None = None
    status: m.Status | None = None
    counters: dict[str, int] = field(
        default_factory=lambda: dict.fromkeys(
            (
                "protocol_errors",
                "refused",
                "wrong_version",
                "sweeps",
                "samples",
                "samples_before_clock",
            ),
            0,
        )
    )
    last_refusal: m.Nak | None = None
    pan_rate_rad_s: float = 0.0  # from the last two statuses' pans
    _seq: int = 0
    _out: bytearray = field(default_factory=bytearray)
    _next_hello: float = -math.inf
    _next_heartbeat: float = -math.inf
    _next_probe: float = -math.inf
    _probes: dict[int, float] = field(default_factory=dict)  # host µs sent -> sent at
    _sent: tuple[float, float, float, bool] | None = None
    _wanted: tuple[float, float, float, bool] | None = None
    _pending: list[FloatArray] = field(default_factory=list)  # samples of the open sweep
    _last_sample_s: float = -math.inf

    @property
    def connected(self) -> bool:
        """The head answered the handshake in this protocol's version."""
        return self.identity is not None and self.identity.protocol_version == m.PROTOCOL_VERSION

    def streaming(self, now_s: float) -> bool:
        """Good samples came within :data:`STREAM_TIMEOUT_S` and the head says its laser is
        on: what ``sensor_ok`` needs of the head."""
        return (
            self.connected
            and self.status is not None
            and self.status.laser_on
            and now_s - self._last_sample_s <= STREAM_TIMEOUT_S
        )

    def _send(self, message: m.Message) -> int:
        seq = self._seq
        self._out += encode_frame(message.TYPE, seq, message.pack())
        self._seq = (seq + 1) % 0x10000
        return seq

    def take_output(self) -> bytes:
        """The bytes to write to the port now."""
        out = bytes(self._out)
        self._out.clear()
        return out

    def command(self, pan_rad: float, low_rad: float, high_rad: float, laser: bool) -> None:
        """What the head should do; sent (pan, window, laser, as they changed) once connected."""
        self._wanted = (pan_rad, low_rad, high_rad, laser)

    def poll(self, now_s: float) -> None:
        """The timed sends: hello until answered, then heartbeats, probes and commands."""
        if not self.connected:
            if now_s >= self._next_hello:
                self._send(m.Hello())
                self._next_hello = now_s + HELLO_RETRY_S
            return
        if now_s >= self._next_heartbeat:
            self._send(m.Heartbeat(round(now_s * 1e6)))
            self._next_heartbeat = now_s + HEARTBEAT_S
        if now_s >= self._next_probe:
            stamp = round(now_s * 1e6)
            self._probes[stamp] = now_s
            self._send(m.TimeRequest(stamp))
            self._next_probe = now_s + TIME_PROBE_S
        if self._wanted is not None and self._wanted != self._sent:
            pan, low, high, laser = self._wanted
            old = self._sent
            if old is None or old[0] != pan:
                self._send(m.Pan(pan))
            if old is None or old[1:3] != (low, high):
                self._send(m.Window(low, high))
            if old is None or old[3] != laser:
                self._send(m.Laser(laser))
            self._sent = self._wanted

    def rearm(self) -> None:
        """Ask the head to leave ``tripped`` (and the laser to come back on as commanded)."""
        self._send(m.Rearm())
        self._sent = None  # send the commands again after it

    def feed(self, data: bytes, now_s: float) -> list[RawScan]:
        """Bytes from the port at ``now_s``; the sweeps they completed."""
        sweeps: list[RawScan] = []
        for frame in self.decoder.feed(data):
            try:
                message = m.decode(frame)
            except m.ProtocolError:
                self.counters["protocol_errors"] += 1
                continue
            if isinstance(message, m.Samples):
                sweeps += self._samples(message, now_s)
            elif isinstance(message, m.Status):
                old = self.status
                if old is not None and message.head_time_us > old.head_time_us:
                    dt = (message.head_time_us - old.head_time_us) * 1e-6
                    self.pan_rate_rad_s = (message.pan_rad - old.pan_rad) / dt
                self.status = message
            elif isinstance(message, m.HelloReply):
                self.identity = message
                if message.protocol_version != m.PROTOCOL_VERSION:
                    self.counters["wrong_version"] += 1
                self._sent = None  # a head that (re)started knows nothing of our commands
            elif isinstance(message, m.TimeReply):
                sent = self._probes.pop(message.host_time_us, None)
                if sent is not None:
                    self.clock.add(sent * 1e6, now_s * 1e6, float(message.head_time_us))
            elif isinstance(message, m.Nak):
                self.counters["refused"] += 1
                self.last_refusal = message
        if now_s - self._last_sample_s > SWEEP_GAP_S and self._pending:
            sweeps += self._close()
        return sweeps

    def _samples(self, frame: m.Samples, now_s: float) -> list[RawScan]:
        if not self.clock.known:  # no clock yet: the samples cannot be placed
            self.counters["samples_before_clock"] += frame.time_us.size
            return []
        self.counters["samples"] += frame.time_us.size
        t = (frame.time_us - self.clock.offset_us) * 1e-6
        block = np.stack([t, frame.scan_rad, frame.pan_rad, frame.i1_A, frame.i2_A])
        out: list[RawScan] = []
        if self._pending and t[0] - self._pending[-1][0, -1] > SWEEP_GAP_S:
            out += self._close()
        self._pending.append(block)
        self._last_sample_s = now_s
        # Cut where the mirror reversed: the sweeps' samples sit half a step from each end,
        # so across a reversal the angle barely moves (the mirror's noise is a twentieth of a
        # step), and the step's sign changes.
        joined = np.concatenate(self._pending, axis=1)
        step = np.diff(joined[1])
        if step.size < 2:
            return out
        small = np.abs(step) < 0.5 * np.median(np.abs(step))
        flips = np.zeros_like(small)
        flips[1:] = (np.sign(step[1:]) != np.sign(step[:-1])) & ~small[1:] & ~small[:-1]
        cuts = np.flatnonzero(small | flips) + 1  # the first sample of each new sweep
        start = 0
        for cut in cuts.tolist():
            if cut - start >= 2:
                out.append(self._sweep(joined[:, start:cut]))
            start = cut
        self._pending = [joined[:, start:]] if start < joined.shape[1] else []
        return out

    def _close(self) -> list[RawScan]:
        joined = np.concatenate(self._pending, axis=1)
        self._pending = []
        return [self._sweep(joined)] if joined.shape[1] >= 2 else []

    def _sweep(self, block: FloatArray) -> RawScan:
        self.counters["sweeps"] += 1
        direction = 1 if block[1, -1] >= block[1, 0] else -1
        return RawScan(block[0], block[1], block[2], block[3], block[4], direction)
