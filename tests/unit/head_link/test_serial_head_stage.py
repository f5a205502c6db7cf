"""The head process's serial backend (agent.stages.serial_head_stage) against the emulated
head on one simulated clock, through a pipe in place of the port: a head at the wrong baud
rate and a head that stops answering are reported (one line, a count, head_state fault),
never raised, and the link recovers once the line is good; a lost port is reopened with
the counts going on."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from agent.runtime import topics
from agent.runtime.messages import HeadState, RawScan
from agent.runtime.stage import Output
from agent.sim.world_file import load_world
from agent.stages.head_stage import HeadStage
from agent.stages.serial_head_stage import NO_FRAME_S, SerialHeadStage
from cli.head_emulator import EmulatedHead, Faults

ROOT = Path(__file__).resolve().parents[3]
PORT = "/dev/ttyTEST0"


class Pipe:
    """The stage's transport to an emulated head, on the test's clock: a read runs the head
    up to now and takes what it sent; ``fail_reads`` makes that many reads raise (a port
    that vanished)."""

    def __init__(self, head: EmulatedHead, clock: list[float]) -> None:
        self.head = head
        self.clock = clock
        self.fail_reads = 0

    def read(self) -> bytes:
        if self.fail_reads:
            self.fail_reads -= 1
            raise OSError("device reports readiness to read but returned no data")
        self.head.step(self.clock[0])
        return self.head.take_output()

    def write(self, data: bytes) -> None:
        self.head.receive(data, self.clock[0])

    def close(self) -> None:
        pass


def _setup(faults: Faults) -> tuple[SerialHeadStage, EmulatedHead, Pipe, list[float]]:
    head = EmulatedHead(HeadStage(load_world(ROOT / "worlds" / "demo.toml"), seed=4), faults=faults)
    clock = [0.0]
    pipe = Pipe(head, clock)
    stage = SerialHeadStage(lambda: pipe, port=PORT, baud=921_600)
    stage.start(0.0)
    return stage, head, pipe, clock


def _run(stage: SerialHeadStage, clock: list[float], seconds: float) -> list[Output]:
    out: list[Output] = []
    end = clock[0] + seconds
    while clock[0] < end - 1e-9:
        clock[0] = round(clock[0] + 0.002, 6)
        out += stage.tick(clock[0])
    return out


def _states(out: list[Output]) -> list[HeadState]:
    return [msg for topic, msg in out if topic == topics.HEAD_STATE]  # type: ignore[misc]


def _scans(out: list[Output]) -> list[RawScan]:
    return [msg for topic, msg in out if topic == topics.RAW_SCAN]  # type: ignore[misc]


def test_a_head_at_the_wrong_baud_rate_is_reported_once_and_kept_at_fault(
    caplog: pytest.LogCaptureFixture,
) -> None:
    stage, head, _, clock = _setup(Faults(baud=115_200))  # the host runs at 921,600
    with caplog.at_level(logging.INFO, logger="agent.stages.serial_head_stage"):
        out = _run(stage, clock, 6.0)
    assert head.baud_mismatch and not stage.link.connected
    assert not _scans(out)
    states = _states(out)
    assert states and all(s.mode == "fault" and not s.laser_on for s in states)
    assert "wrong baud rate" in states[-1].command_message
    assert states[0].command_message != states[-1].command_message  # said once it is known
    counts = stage.counters()
    assert counts["line_garbled"] == 1 and counts["head_silent"] == 0  # one spell
    assert counts["frames"] == 0 and counts["bytes_dropped"] > 0  # garbage, all of it dropped
    (line,) = [r.getMessage() for r in caplog.records]
    assert line.startswith(f"no valid frame from {PORT} in 2.0 s at 921600 baud (")
    assert "wrong baud rate, or not a head" in line

    caplog.clear()
    head.host_baud = 115_200  # the host's rate put right: the line reads whole
    with caplog.at_level(logging.INFO, logger="agent.stages.serial_head_stage"):
        out = _run(stage, clock, 2.0)
    assert stage.link.connected and len(_scans(out)) >= 10
    assert _states(out)[-1].mode == "scanning" and _states(out)[-1].command_message == ""
    (line,) = [r.getMessage() for r in caplog.records]
    assert line.startswith(f"valid frames from {PORT} again, after 6.")
    assert stage.counters()["line_garbled"] == 1


def test_a_head_that_stops_answering_is_at_fault_and_reported(
    caplog: pytest.LogCaptureFixture,
) -> None:
    stage, _, _, clock = _setup(Faults(silent_at_s=1.5))
    out = _run(stage, clock, 1.5)
    assert len(_scans(out)) >= 5 and _states(out)[-1].mode == "scanning"
    with caplog.at_level(logging.INFO, logger="agent.stages.serial_head_stage"):
        out = _run(stage, clock, 0.3)
        # The samples stop: fault within the link's 0.2 s stream timeout and a state period.
        faults = [s for s in _states(out) if s.mode == "fault"]
        assert faults and faults[0].header.stamp_s <= 1.5 + 0.2 + 0.1 + 0.01
        assert faults[-1].command_message == "no samples from the head"
        out = _run(stage, clock, NO_FRAME_S)
    assert all(s.mode == "fault" for s in _states(out))
    assert "the head is not answering" in _states(out)[-1].command_message
    assert stage.counters()["head_silent"] == 1 and stage.counters()["line_garbled"] == 0
    (line,) = [r.getMessage() for r in caplog.records]
    assert line.startswith(f"nothing from {PORT} in 2.0 s: the head is not answering")


def test_a_lost_port_is_reopened_and_the_counts_go_on() -> None:
    stage, _, pipe, clock = _setup(Faults())
    _run(stage, clock, 1.0)
    frames = stage.counters()["frames"]
    assert frames > 50
    pipe.fail_reads = 1
    out = _run(stage, clock, 0.05)
    assert _states(out)[-1].command_message == "serial port not open"
    out = _run(stage, clock, 1.0)  # reopened after 0.1 s, the handshake again
    counts = stage.counters()
    assert (counts["port_lost"], counts["reconnects"]) == (1, 1)
    assert counts["frames"] > frames  # not started again from zero with the new link
    assert _states(out)[-1].mode == "scanning"
