"""The head's firmware emulation (cli.head_emulator) driven in simulated time over the
protocol: handshake, commands, samples at the sensor's rate, refusals, and the laser's
safety when the host goes quiet or the mirror fails."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.errors import ConfigError
from agent.head_link import messages as m
from agent.head_link.frames import FrameDecoder, encode_frame
from agent.head_link.host import HeadLink
from agent.sim.world_file import load_world
from agent.stages.head_stage import HeadStage
from cli.head_emulator import EmulatedHead, Faults, uart_garble
from tests.unit.head_link.test_link_protocol import _stream  # noqa: F401 (same framing)

ROOT = __import__("pathlib").Path(__file__).resolve().parents[3]


class Host:
    """A minimal host: sends commands, keeps what the head said."""

    def __init__(self, head: EmulatedHead) -> None:
        self.head = head
        self.decoder = FrameDecoder()
        self.seq = 0
        self.got: list[object] = []
        self.t = 0.0

    def send(self, message: object) -> int:
        seq = self.seq
        data = encode_frame(message.TYPE, seq, message.pack())  # type: ignore[attr-defined]
        self.head.receive(data, self.t)
        self.seq += 1
        return seq

    def run(self, seconds: float, heartbeat: bool = True) -> None:
        end = self.t + seconds
        while self.t < end - 1e-9:
            self.t = round(self.t + 0.01, 6)
            if heartbeat and round(self.t * 100) % 10 == 0:
                self.send(m.Heartbeat(round(self.t * 1e6)))
            self.head.step(self.t)
            for frame in self.decoder.feed(self.head.take_output()):
                self.got.append(m.decode(frame))

    def of(self, kind: type) -> list:
        return [x for x in self.got if isinstance(x, kind)]


def _head(faults: Faults | None = None) -> tuple[Host, EmulatedHead]:
    world = load_world(ROOT / "worlds" / "demo.toml")
    head = EmulatedHead(HeadStage(world, seed=1), faults=faults or Faults())
    return Host(head), head


def _start(host: Host) -> None:
    host.send(m.Hello())
    host.send(m.Heartbeat(0))
    host.run(0.05)
    assert host.send(m.Window(-0.349, 0.349)) >= 0
    host.send(m.Pan(0.5))
    host.send(m.Laser(True))
    host.run(0.05)


def test_handshake_commands_and_samples_at_the_sensors_rate() -> None:
    host, _ = _head()
    _start(host)
    (reply,) = host.of(m.HelloReply)
    assert reply.protocol_version == m.PROTOCOL_VERSION and reply.firmware
    assert [a.command_type for a in host.of(m.Ack)] == [m.Window.TYPE, m.Pan.TYPE, m.Laser.TYPE]
    before = sum(s.time_us.size for s in host.of(m.Samples))
    host.run(1.0)
    samples = host.of(m.Samples)
    count = sum(s.time_us.size for s in samples) - before
    assert abs(count - 2560) <= 256  # 2,560 a second, to a sweep
    last = samples[-1]
    assert np.all(np.abs(last.pan_rad - 0.5) < 1e-3)  # slewed to the commanded pan
    assert np.all(np.abs(last.scan_rad) <= 0.35)
    statuses = host.of(m.Status)
    assert 10 <= len(statuses) <= 13 and statuses[-1].state is m.SafetyState.ON


def test_commands_it_cannot_honour_are_refused_and_turn_the_laser_off() -> None:
    host, head = _head()
    _start(host)
    bad = host.send(m.Window(-0.5, 0.5))  # beyond ±20°
    host.run(0.05)
    (nak,) = host.of(m.Nak)
    assert (nak.seq, nak.reason) == (bad, m.Reason.OUT_OF_RANGE)
    assert head.safety.state is m.SafetyState.TRIPPED
    n = len(host.of(m.Samples))
    host.run(0.5)
    assert len(host.of(m.Samples)) == n  # no samples with the laser off
    host.send(m.Laser(True))
    host.send(m.Rearm())
    host.send(m.Laser(True))
    host.run(0.3)
    reasons = [k.reason for k in host.of(m.Nak)]
    assert reasons == [m.Reason.OUT_OF_RANGE, m.Reason.LASER_LOCKED]
    assert head.safety.laser_on and len(host.of(m.Samples)) > n


def test_a_quiet_host_or_a_stalled_mirror_turns_the_laser_off() -> None:
    host, head = _head()
    _start(host)
    host.run(0.3)
    host.run(0.7, heartbeat=False)  # last heartbeat at 0.4 s: tripped by 0.901 s
    assert head.safety.cause.name == "HEARTBEAT_LOST"
    assert head.safety.tripped_at_s == pytest.approx(0.901, abs=0.002)

    host, head = _head(Faults(stall_at_s=0.5))
    _start(host)
    host.run(1.0)
    assert head.safety.cause.name == "MIRROR_STALL"
    assert 0.5 < head.safety.tripped_at_s < 0.6


def test_clock_probes_and_a_garbled_line() -> None:
    host, _ = _head(Faults(flip=0.002, garbage_at_s=0.2))
    _start(host)
    host.send(m.TimeRequest(123))
    host.run(1.0)
    (reply,) = host.of(m.TimeReply)
    assert reply.host_time_us == 123
    # One bit in 500 bytes flipped: a 470-byte samples frame survives (0.998)^470 = 39 % of
    # the time; every damaged one is caught (a body that passed its CRC would not decode).
    assert host.decoder.counters.dropped > 20 and len(host.of(m.Samples)) > 20


def test_fault_specs_are_checked() -> None:
    assert Faults.parse("stall@2.5, drop=0.01") == Faults(stall_at_s=2.5, drop=0.01)
    assert Faults.parse("truncate=0.1,baud=115200") == Faults(truncate=0.1, baud=115_200)
    for bad in ("melt@1", "drop=2", "stall@x", "silent@-1", "truncate=1.5", "baud=0",
                "baud=9600.5", "baud=5000000", "baud@9600"):  # fmt: skip
        with pytest.raises(ConfigError, match="--faults"):
            Faults.parse(bad)
    assert math.isinf(Faults.parse("").silent_at_s) and Faults.parse("").baud == 0


def test_truncated_frames_are_counted_by_the_host_which_reads_on() -> None:
    # Every frame the head sends either reaches the host or is counted missing there (by
    # sequence number); each cut costs at most itself and the frame it runs into; the host
    # goes on streaming.
    world = load_world(ROOT / "worlds" / "demo.toml")
    head = EmulatedHead(HeadStage(world, seed=2), faults=Faults(truncate=0.1), seed=5)
    link = HeadLink()
    link.command(0.0, -0.349, 0.349, True)
    t = 0.0
    sweeps = 0
    while t < 3.0:
        t = round(t + 0.002, 6)
        link.poll(t)
        head.receive(link.take_output(), t)
        head.step(t)
        sweeps += len(link.feed(head.take_output(), t))
    c = link.decoder.counters
    assert head.truncated >= 20  # of about 95 frames a second
    assert 1 <= c.dropped <= head.truncated
    assert head.truncated <= c.seq_gaps <= 2 * head.truncated
    # The last frame may be waiting for its delimiter; none is lost uncounted.
    assert head.frames_sent - 1 <= c.frames + c.seq_gaps <= head.frames_sent
    assert link.streaming(t) and sweeps >= 20


def test_the_uart_model_at_the_wrong_rate() -> None:
    data = np.random.default_rng(6).integers(0, 256, 2000, dtype=np.uint8).tobytes()
    # Rates within the tolerance of a UART (the stop bit's sample still in the stop bit).
    for read_baud in (921_600, 960_000, 884_000):
        assert uart_garble(data, 921_600, read_baud) == data
    # Worked by hand. A reader at half the rate sees 0x00 as its start bit, three zeros,
    # the stop bit and idle line: 0xF8, stop bit high. At twice the rate, 0x00 is low
    # through its own stop bit's sample (a framing error: 0x00) and 0xFF reads its start
    # bit as a zero data bit, then ones: 0xFE.
    assert uart_garble(b"\x00", 100, 50) == b"\xf8"
    assert uart_garble(b"\x00", 100, 200) == b"\x00"
    assert uart_garble(b"\xff", 100, 200) == b"\xfe"
    slow = uart_garble(data, 921_600, 115_200)
    fast = uart_garble(data, 115_200, 921_600)
    assert len(slow) < len(data) / 5 and len(fast) > 2 * len(data)
    assert uart_garble(data, 921_600, 115_200) == slow  # deterministic
    # What either end reads of frames sent at the other rate: nothing good, all counted.
    frames = encode_frame(m.Status.TYPE, 0, b"\x01" * 46) * 20
    for garbled in (uart_garble(frames, 921_600, 115_200), uart_garble(frames, 115_200, 921_600)):
        decoder = FrameDecoder()
        assert decoder.feed(garbled) == [] and decoder.counters.dropped > 0


def test_a_head_at_another_baud_rate_never_answers_until_the_rates_agree() -> None:
    host, head = _head(Faults(baud=115_200))
    _start(host)
    host.run(1.0)
    assert head.baud_mismatch and not head.greeted and host.got == []
    assert host.decoder.counters.bytes > 0  # it talks, garbled
    head.host_baud = 115_200
    host.send(m.Hello())  # runs into the garbage the head read before, and is lost
    _start(host)
    host.run(0.5)
    assert head.greeted and host.of(m.HelloReply) and host.of(m.Samples)
