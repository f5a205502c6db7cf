"""The head's firmware emulator on a real pseudo-terminal, spoken to with pyserial: the
handshake, samples at the sensor's rate, and the laser off once the host goes quiet."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

serial = pytest.importorskip("serial")

from agent.head_link import messages as m  # noqa: E402
from agent.head_link.frames import FrameDecoder, encode_frame  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def test_the_emulated_head_over_a_pty() -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "cli.main", "head-emulator", "--duration", "20"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        port = proc.stdout.readline().strip()
        assert port.startswith("/dev/"), port
        link = serial.Serial(port, 921600, timeout=0.05)
        seq = 0

        def send(message: object) -> None:
            nonlocal seq
            link.write(encode_frame(message.TYPE, seq, message.pack()))  # type: ignore[attr-defined]
            seq += 1

        decoder = FrameDecoder()
        got: list[object] = []
        # The handshake first, as the head process does: an emulator still starting (slow
        # under a loaded machine) would otherwise take the laser command before its mirror
        # is up to speed and refuse it.
        send(m.Hello())
        deadline = time.monotonic() + 10.0
        while not any(isinstance(x, m.HelloReply) for x in got):
            assert time.monotonic() < deadline, f"no hello reply within 10 s: {got}"
            got.extend(m.decode(frame) for frame in decoder.feed(link.read(65536)))
        send(m.Heartbeat(0))
        send(m.Window(-0.349, 0.349))
        send(m.Laser(True))
        started = time.monotonic()
        samples_while_on = 0
        tripped_at = None
        while time.monotonic() - started < 3.5 and tripped_at is None:
            elapsed = time.monotonic() - started
            if elapsed < 1.5:
                send(m.Heartbeat(round(elapsed * 1e6)))
            for frame in decoder.feed(link.read(65536)):
                message = m.decode(frame)
                got.append(message)
                if isinstance(message, m.Samples) and 0.5 <= elapsed < 1.5:
                    samples_while_on += message.time_us.size
                if isinstance(message, m.Status) and message.state is m.SafetyState.TRIPPED:
                    tripped_at = elapsed
            time.sleep(0.02)
        assert any(isinstance(x, m.HelloReply) for x in got)
        assert [x.command_type for x in got if isinstance(x, m.Ack)] == [
            m.Window.TYPE, m.Laser.TYPE,
        ], [x for x in got if isinstance(x, m.Nak)]  # fmt: skip
        # 2,560 samples a second over the second with heartbeats, in real time on a shared
        # machine (the exact rate is checked on the emulator's own clock in the unit tests).
        assert 1500 <= samples_while_on <= 3600
        # The last heartbeat near 1.5 s; the laser off 0.5 s later (plus the status period
        # and this loop's reads).
        assert tripped_at is not None and 1.9 <= tripped_at <= 2.8
        assert decoder.counters.dropped == 0
    finally:
        proc.terminate()
        proc.wait(10)


def test_a_head_at_another_baud_rate_is_garbled_until_the_host_matches_it() -> None:
    # The emulator reads the rate pyserial set on the pseudo-terminal: at 921,600 against
    # its 115,200 every byte each way is garbled (no frame, no answer to hello); once the
    # host's port is set to 115,200 the handshake goes through.
    proc = subprocess.Popen(
        [sys.executable, "-m", "cli.main", "head-emulator", "--faults", "baud=115200",
         "--duration", "20"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        port = proc.stdout.readline().strip()
        link = serial.Serial(port, 921600, timeout=0.05)

        def exchange(seconds: float) -> tuple[list[object], FrameDecoder]:
            decoder = FrameDecoder()
            got: list[object] = []
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                link.write(encode_frame(m.Hello.TYPE, 0, m.Hello().pack()))
                got += [m.decode(frame) for frame in decoder.feed(link.read(65536))]
                time.sleep(0.05)
            return got, decoder

        got, decoder = exchange(1.5)
        assert got == [] and decoder.counters.bytes > 100  # its status, garbled
        assert decoder.counters.dropped > 0
        link.baudrate = 115200
        time.sleep(0.2)  # the emulator reads the rate every 50 ms
        link.reset_input_buffer()
        got, decoder = exchange(1.0)
        assert any(isinstance(x, m.HelloReply) for x in got), got
        assert any(isinstance(x, m.Status) for x in got)
    finally:
        proc.terminate()
        proc.wait(10)
