"""``sensor-agent head-emulator [--world W] [--seed S] [--faults SPEC] [--link PATH]
[--duration S]``: the head's firmware on a pseudo-terminal, backed by the simulator.

It prints the port to connect to (``/dev/pts/N``; ``--link`` also makes ``PATH`` a symlink
to it, which a launch file can name), then speaks ``docs/head-protocol.md``
there until stopped: the handshake, ``pan``, ``window`` and ``laser`` commands acknowledged
or refused with a reason, status at 10 Hz, clock probes answered, and every sweep of the
simulated head (:class:`agent.stages.head_stage.HeadStage`: the pan axis and the physics of
the chapter) as samples frames of 32. The laser's safety state machine
(:class:`agent.head_link.safety.LaserSafety`) runs at 1 kHz over the mirror model: no
heartbeat for 0.5 s, a mirror fault or a command it cannot honour switches the laser off
until ``rearm``.

**Faults** (``--faults``, comma-separated): ``stall@T`` and ``slow@T`` (the mirror fails at
``T`` s), ``silent@T`` (the firmware stops answering at ``T``), ``drop=P`` and ``flip=P``
(each byte it sends is lost, or has a bit flipped, with probability ``P``), ``garbage@T``
(200 random bytes at ``T``), ``truncate=P`` (each frame it sends is cut short, with
probability ``P``, after 1 to all of its stuffed bytes: the rest and its delimiter are never
sent, so the host's decoder reads it and the frame after it as one bad chunk and is whole
again at the next), ``baud=N`` (the head's UART runs at ``N`` baud; see below).

**A wrong baud rate.** A pseudo-terminal has no line rate, but it keeps the one the host set
(pyserial's ``baudrate``): :func:`serve` reads it from the terminal's settings
(``tcgetattr``, every 50 ms). While it differs from ``baud=N``, the bytes each way pass
through :func:`uart_garble`, a deterministic model of a UART receiving at the wrong rate:
the sender's bytes (a start bit, 8 data bits least significant first, a stop bit, back
to back within one write or read, the line idle high around them) are read by a receiver
that waits for a falling edge, then samples the middle of each of its own bit times (the
start bit again, else it was a glitch and it hunts on; then 8 data bits, then the stop
bit); a stop bit read low is a framing error, which a tty passes on as ``0x00`` (Linux
without ``PARMRK`` or ``IGNPAR``, as pyserial configures it). Rates within about 5 % of
each other read every byte whole, as real UARTs do; beyond, the host sees bytes of
fragments and zeros, and the head no frame of the host's. Throughput is not modelled: the
bytes come as fast as the emulated head makes them, whatever the rates.

``--truth ENDPOINT`` (a graph's ``world`` process endpoint)
gives it the vehicle's true motion, as the simulated head takes it in the graph; without it
the vehicle stands at the world's start pose. It runs on the graph's clock (wall time).

:class:`EmulatedHead` is the firmware without the port (bytes in, bytes out, on a clock it
is given), so that tests drive it in simulated time; :func:`serve` runs it on a file
descriptor in real time.
"""

from __future__ import annotations

import argparse
import math
import os
import select
import termios
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from agent.errors import ConfigError
from agent.head_link import messages as m
from agent.head_link.frames import FrameDecoder, encode_frame
from agent.head_link.safety import (
    SCAN_HALF_RAD,
    WIRE_STEP_RAD,
    LaserSafety,
    Mirror,
    SafetySettings,
    check_window,
)
from agent.runtime.messages import HeadCommand, Header, RawScan, WorldTruth, stamp_ns
from agent.sim.world_file import load_world
from agent.stages.head_stage import HeadStage

FIRMWARE = "emulator-1.0"
STATUS_PERIOD_S = 0.1
SAMPLES_PER_FRAME = 32
PAN_LIMIT_RAD = math.radians(90.0)
LINE_BAUD = 921_600  # the protocol's rate (docs/head-protocol.md §1)
TTY_SPEED_EVERY_S = 0.05  # how often serve() reads the rate the host set on the terminal
MAX_BAUD = 4_000_000  # the fastest rate a Linux terminal names (termios.B4000000)


_FAULT_KEYS = {
    "stall@": "stall_at_s", "slow@": "slow_at_s", "silent@": "silent_at_s",
    "garbage@": "garbage_at_s", "drop=": "drop", "flip=": "flip", "truncate=": "truncate",
    "baud=": "baud",
}  # fmt: skip
_PROBABILITIES = ("drop", "flip", "truncate")
_FAULT_SYNTAX = (
    "stall@T, slow@T, silent@T, garbage@T, drop=P, flip=P, truncate=P, baud=N "
    "(T seconds >= 0, P a probability, N a whole number of baud)"
)
# A terminal's speed constants (termios.B9600, ...) by the rates they name.
_TTY_SPEEDS = {
    getattr(termios, name): int(name[1:])
    for name in dir(termios)
    if name.startswith("B") and name[1:].isdigit()
}


def uart_garble(data: bytes, sent_baud: int, read_baud: int) -> bytes:
    """What a UART reading at ``read_baud`` makes of ``data`` sent at ``sent_baud``: the
    module docstring's model (no change when the rates agree).

    Times are counted in the sender's bit times; the receiver's bit lasts
    ``r = sent_baud / read_baud`` of them. Each falling edge of the line is where a receiver
    that is hunting starts a byte; the byte it then reads ends (and the hunt resumes) at its
    stop bit's sample, ``9.5 r`` later, or at ``0.5 r`` for a start bit read high (a glitch).
    """
    if sent_baud == read_baud or not data:
        return data
    if sent_baud <= 0 or read_baud <= 0:
        raise ValueError(f"baud rates must be positive, got {sent_baud} and {read_baud}")
    r = sent_baud / read_baud
    sent = np.frombuffer(data, dtype=np.uint8)
    frames = np.ones((sent.size, 10), dtype=np.uint8)  # start, 8 data bits, stop
    frames[:, 0] = 0
    frames[:, 1:9] = np.unpackbits(sent[:, None], axis=1, bitorder="little")
    line = frames.ravel()  # the level in each of the sender's bit times; idle (1) around

    def level(t: np.ndarray) -> np.ndarray:
        i = np.floor(t).astype(np.int64)
        return np.where(i < line.size, line[np.minimum(i, line.size - 1)], 1)

    before = np.concatenate(([1], line[:-1]))
    edges = np.flatnonzero((before == 1) & (line == 0)).astype(np.float64)
    start_low = level(edges + 0.5 * r) == 0
    resume = edges + np.where(start_low, 9.5 * r, 0.5 * r)
    following = np.searchsorted(edges, resume, side="right").tolist()
    low = start_low.tolist()
    read: list[int] = []  # the edges whose bytes the receiver reads, in order
    i = 0
    while i < edges.size:  # one step a byte read (or a glitch): a chain through the edges
        if low[i]:
            read.append(i)
        i = following[i]
    starts = edges[read]
    bits = level(starts[:, None] + (np.arange(1, 10) + 0.5) * r)  # data bits, then the stop
    value = (bits[:, :8].astype(np.int64) << np.arange(8)).sum(axis=1)
    value[bits[:, 8] == 0] = 0  # a framing error: 0x00
    return value.astype(np.uint8).tobytes()


@dataclass(frozen=True)
class Faults:
    """What to inject (module docstring)."""

    stall_at_s: float = math.inf
    slow_at_s: float = math.inf
    silent_at_s: float = math.inf
    garbage_at_s: float = math.inf
    drop: float = 0.0
    flip: float = 0.0
    truncate: float = 0.0
    baud: int = 0  # the head's UART rate; 0: whatever the host set

    @classmethod
    def parse(cls, spec: str) -> Faults:
        """``stall@T,slow@T,silent@T,garbage@T,drop=P,flip=P,truncate=P,baud=N`` (any)."""
        values: dict[str, float] = {}
        for item in filter(None, (s.strip() for s in spec.split(","))):
            name, sep, number = item.partition("@" if "@" in item else "=")
            try:
                value = float(number)
            except ValueError:
                value = math.nan
            key = _FAULT_KEYS.get(name + sep)
            if key is None or not math.isfinite(value) or value < 0:
                raise ConfigError(f"--faults: {item!r} is not one of {_FAULT_SYNTAX}")
            if key in _PROBABILITIES and value > 1:
                raise ConfigError(f"--faults: {item!r}: a probability is at most 1")
            if key == "baud" and not (value == int(value) and 1 <= value <= MAX_BAUD):
                raise ConfigError(
                    f"--faults: {item!r}: a baud rate is a whole number from 1 to {MAX_BAUD}"
                )
            values[key] = value
        baud = int(values.pop("baud", 0))
        return cls(**values, baud=baud)


@dataclass
class EmulatedHead:
    """The firmware (module docstring); times in seconds on its own clock."""

    stage: HeadStage
    serial_number: str = "EMU-0001"
    calibration_id: str = "simulated"
    faults: Faults = field(default_factory=Faults)
    seed: int = 0
    settings: SafetySettings = field(default_factory=SafetySettings)
    start_s: float = 0.0  # its clock at start: the faults' times and the mirror's count from it
    host_baud: int = LINE_BAUD  # the rate the host's end runs at (serve() reads it)

    def __post_init__(self) -> None:
        self.decoder = FrameDecoder()
        self.safety = LaserSafety(self.settings)
        self.mirror = Mirror(self.settings)
        if math.isfinite(self.faults.stall_at_s):
            self.mirror.fault, self.mirror.fault_at_s = "stall", self.faults.stall_at_s
        elif math.isfinite(self.faults.slow_at_s):
            self.mirror.fault, self.mirror.fault_at_s = "slow", self.faults.slow_at_s
        self.rng = np.random.default_rng(self.seed)
        self.greeted = False
        self.refused = 0
        self._seq = 0
        self._next_tick = self.start_s
        self._next_status = self.start_s
        self._pan = 0.0
        self._window = (-SCAN_HALF_RAD, SCAN_HALF_RAD)
        self._garbage_sent = False
        self._out = bytearray()
        self.frames_sent = 0
        self.truncated = 0  # frames cut short (truncate=P)
        self.stage.start(self.start_s)
        self._stage_laser(False, self.start_s)

    # --------------------------------------------------------------------------- output
    @property
    def baud_mismatch(self) -> bool:
        """The head's UART (``baud=N``) and the host's end run at different rates."""
        return self.faults.baud != 0 and self.faults.baud != self.host_baud

    def _send(self, message: m.Message) -> None:
        frame = encode_frame(message.TYPE, self._seq, message.pack())
        if self.faults.truncate and self.rng.random() < self.faults.truncate:
            # Cut after 1 to all of its stuffed bytes; the delimiter never goes.
            frame = frame[: int(self.rng.integers(1, len(frame)))]
            self.truncated += 1
        self._out += frame
        self.frames_sent += 1
        self._seq = (self._seq + 1) % 0x10000

    def take_output(self) -> bytes:
        """What to write to the port now (with the injected line faults)."""
        out = bytes(self._out)
        self._out.clear()
        f = self.faults
        if out and (f.drop or f.flip):
            data = np.frombuffer(out, dtype=np.uint8).copy()
            if f.flip:
                hit = self.rng.random(data.size) < f.flip
                data[hit] ^= (1 << self.rng.integers(0, 8, int(hit.sum()))).astype(np.uint8)
            if f.drop:
                data = data[self.rng.random(data.size) >= f.drop]
            out = data.tobytes()
        if self.baud_mismatch:
            out = uart_garble(out, self.faults.baud, self.host_baud)
        return out

    # ---------------------------------------------------------------------------- input
    def receive(self, data: bytes, now_s: float) -> None:
        """Bytes from the host, at ``now_s``."""
        if now_s - self.start_s >= self.faults.silent_at_s:
            return
        if self.baud_mismatch:
            data = uart_garble(data, self.host_baud, self.faults.baud)
        for frame in self.decoder.feed(data):
            try:
                message = m.decode(frame)
            except m.ProtocolError as exc:
                reason = (
                    m.Reason.UNKNOWN_TYPE if "not in protocol" in str(exc) else m.Reason.MALFORMED
                )
                self._nak(frame.seq, frame.type, reason, str(exc), now_s)
                continue
            self._handle(frame.seq, message, now_s)

    def _nak(self, seq: int, kind: int, reason: m.Reason, text: str, now_s: float) -> None:
        self.refused += 1
        if kind in (m.Pan.TYPE, m.Window.TYPE, m.Laser.TYPE) and reason in (
            m.Reason.MALFORMED, m.Reason.OUT_OF_RANGE,
        ):  # fmt: skip
            self.safety.bad_command(now_s)  # a command it cannot honour: the laser goes off
            self._stage_laser(False, now_s)
        self._send(m.Nak(seq, kind, reason, text[:48]))

    def _handle(self, seq: int, message: object, now_s: float) -> None:
        if isinstance(message, m.Hello):
            self.greeted = message.protocol_version == m.PROTOCOL_VERSION
            self._send(m.HelloReply(m.PROTOCOL_VERSION, FIRMWARE, self.serial_number,
                                    self.calibration_id))  # fmt: skip
            return
        if isinstance(message, m.Heartbeat):
            self.safety.heartbeat(now_s)
            return
        kind = message.TYPE  # type: ignore[attr-defined]
        if isinstance(message, m.TimeRequest):
            self._send(m.TimeReply(message.host_time_us, round(now_s * 1e6)))
            return
        if not self.greeted:
            self._nak(seq, kind, m.Reason.NOT_READY, "hello first", now_s)
            return
        if isinstance(message, m.Pan):
            if not abs(message.target_rad) <= PAN_LIMIT_RAD + WIRE_STEP_RAD:  # ±90°, in µrad
                self._nak(seq, kind, m.Reason.OUT_OF_RANGE, "pan beyond +-90 deg", now_s)
                return
            self._pan = max(-PAN_LIMIT_RAD, min(PAN_LIMIT_RAD, message.target_rad))
            self._command(now_s)
        elif isinstance(message, m.Window):
            why = check_window(message.low_rad, message.high_rad)
            if why is not None:
                self._nak(seq, kind, why, "window beyond +-20 deg or under 2 deg", now_s)
                return
            # Taken within the wire's µrad, held to the mirror's ±20°.
            self._window = (
                max(-SCAN_HALF_RAD, message.low_rad),
                min(SCAN_HALF_RAD, message.high_rad),
            )
            self._command(now_s)
        elif isinstance(message, m.Laser):
            why = self.safety.laser(now_s, message.on)
            if why is not None:
                self._nak(seq, kind, why, "laser refused", now_s)
                return
            self._stage_laser(message.on, now_s)
        elif isinstance(message, m.Rearm):
            why = self.safety.rearm(now_s)
            if why is not None:
                self._nak(seq, kind, why, "the fault is still there", now_s)
                return
        elif isinstance(message, m.StatusRequest):
            self._send(self.status(now_s))
        else:  # a head's own message sent to the head
            self._nak(seq, kind, m.Reason.UNKNOWN_TYPE, "not a command", now_s)
            return
        self._send(m.Ack(seq, kind))

    # ----------------------------------------------------------------------- the head
    def _command(self, now_s: float) -> None:
        self._stage_laser(self.safety.laser_on, now_s)

    def _stage_laser(self, on: bool, now_s: float) -> None:
        low, high = self._window
        self.stage.handle(
            "head_command",
            HeadCommand(
                header=Header(stamp_ns=stamp_ns(now_s)), pan_rad=self._pan,
                window_low_rad=low, window_high_rad=high, laser=on,
            ),
            now_s,
        )  # fmt: skip

    def status(self, now_s: float) -> m.Status:
        c = self.decoder.counters
        return m.Status(
            round(now_s * 1e6), self.safety.state, self.safety.laser_on,
            self.mirror.rate_rad_s, self.stage.pan.position_rad, self.stage.pan.target_rad,
            self._window[0], self._window[1], c.frames, c.crc_errors, self.refused,
            self.safety.trips,
        )  # fmt: skip

    def step(self, now_s: float) -> None:
        """Run the firmware up to ``now_s``: safety ticks, sweeps, status."""
        if now_s - self.start_s >= self.faults.silent_at_s:
            return
        if not self._garbage_sent and now_s - self.start_s >= self.faults.garbage_at_s:
            self._out += self.rng.integers(0, 256, 200, dtype=np.uint8).tobytes()
            self._garbage_sent = True
        while self._next_tick <= now_s:
            t = self._next_tick
            was_on = self.safety.laser_on
            self.safety.tick(t, self.mirror.advance(t - self.start_s))
            if was_on and not self.safety.laser_on:
                self._stage_laser(False, t)
            next_stage = self.stage.next_tick_s()
            if next_stage is not None and next_stage <= t:
                for topic, msg in self.stage.tick(t):
                    if topic == "raw_scan" and self.safety.laser_on:
                        self._samples(msg)  # type: ignore[arg-type]
            if t >= self._next_status:
                self._send(self.status(t))
                self._next_status = t + STATUS_PERIOD_S
            self._next_tick = t + self.settings.tick_s

    def _samples(self, scan: RawScan) -> None:
        n = scan.time_s.size
        for lo in range(0, n, SAMPLES_PER_FRAME):
            hi = min(n, lo + SAMPLES_PER_FRAME)
            self._send(
                m.Samples.of(
                    scan.time_s[lo:hi] * 1e6, scan.mirror_angle_rad[lo:hi], scan.pan_rad[lo:hi],
                    scan.current_1_A[lo:hi], scan.current_2_A[lo:hi],
                )
            )  # fmt: skip


def tty_baud(fd: int) -> int | None:
    """The rate a terminal is set to (its output speed, as pyserial sets both), or ``None``
    for one that ``termios`` does not name (a custom rate) or a descriptor that is no
    terminal."""
    try:
        speed = termios.tcgetattr(fd)[5]
    except termios.error:
        return None
    return _TTY_SPEEDS.get(speed)


def serve(
    head: EmulatedHead,
    fd: int,
    duration_s: float = math.inf,
    clock: Callable[[], float] = time.time,
    truth: Callable[[], list[WorldTruth]] | None = None,
    tty: int | None = None,
) -> None:
    """Run ``head`` on ``fd`` (a pty's master) in real time, 1 ms at a time, on ``clock``
    (the graph's: wall time), feeding it the vehicle's true motion from ``truth``. ``tty``
    (the pty's slave) is where the host's rate is read, for ``baud=N`` (a rate it cannot
    read leaves the last one known, at first the protocol's)."""
    os.set_blocking(fd, False)
    started = clock()
    next_speed = started
    while (now := clock()) - started < duration_s:
        if tty is not None and head.faults.baud and now >= next_speed:
            head.host_baud = tty_baud(tty) or head.host_baud
            next_speed = now + TTY_SPEED_EVERY_S
        ready, _, _ = select.select([fd], [], [], 0.001)
        if truth is not None:
            for msg in truth():
                head.stage.handle("world_truth", msg, now)
        if ready:
            try:
                data = os.read(fd, 4096)
            except (BlockingIOError, InterruptedError):
                data = b""
            except OSError:  # the other side closed: wait for it to come back
                data = b""
            if data:
                head.receive(data, now)
        head.step(now)
        out = head.take_output()
        while out:
            try:
                written = os.write(fd, out)
            except BlockingIOError:
                time.sleep(0.0005)
                continue
            except OSError:
                break
            out = out[written:]


def _truth_feed(endpoint: str) -> tuple[Callable[[], list[WorldTruth]], Callable[[], None]]:
    """The vehicle's true motion from a graph's ``world_truth`` (the world process's
    endpoint), and a closer."""
    from agent.runtime import topics
    from agent.runtime.bus import Bus
    from agent.runtime.messages import decode

    bus = Bus(None)
    bus.subscriber.connect(endpoint)
    bus.subscriber.subscribe(topics.WORLD_TRUTH)

    def poll() -> list[WorldTruth]:
        got = []
        for _, payload in bus.poll(0.0):
            msg = decode(payload)
            if isinstance(msg, WorldTruth):
                got.append(msg)
        return got

    return poll, bus.close


def head_emulator_command(args: argparse.Namespace) -> int:
    """``sensor-agent head-emulator``: prints the port, serves until Ctrl-C or --duration."""
    faults = Faults.parse(args.faults or "")
    world = load_world(Path(args.world))
    head = EmulatedHead(
        HeadStage(world, seed=args.seed), faults=faults, seed=args.seed, start_s=time.time()
    )
    truth, close_truth = _truth_feed(args.truth) if args.truth else (None, None)
    master, slave = os.openpty()
    import tty

    tty.setraw(slave)
    port = os.ttyname(slave)
    link = Path(args.link) if args.link else None
    if link is not None:
        if link.exists() and not link.is_symlink():
            raise ConfigError(f"head-emulator: --link {link} exists and is not a symlink")
        link.unlink(missing_ok=True)
        link.symlink_to(port)
    print(port, flush=True)
    try:
        duration = args.duration if args.duration is not None else math.inf
        serve(head, master, duration, truth=truth, tty=slave)
    finally:
        if close_truth is not None:
            close_truth()
        os.close(master)
        os.close(slave)
        if link is not None and link.is_symlink() and os.readlink(link) == port:
            link.unlink()
    return 0
