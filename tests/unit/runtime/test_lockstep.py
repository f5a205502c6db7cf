"""Tests of agent.runtime.lockstep: how the runner stamps what a stage publishes.

A publisher sets each message's ``seq`` (per node and topic), ``source`` (the node's name)
and, where the stage left it 0, ``stamp_ns`` (the simulated clock). Serialising stamps on
the wire; not serialising stamps a copy; both give the same messages.
"""

from __future__ import annotations

import numpy as np
import pytest

from agent.runtime import topics
from agent.runtime.lockstep import LockstepRunner, Node
from agent.runtime.messages import Header, Message, Stop, WheelCommand, stamp_ns
from agent.runtime.stage import Output, Stage

pytestmark = pytest.mark.filterwarnings("error")


class _Ticker(Stage):
    """A wheel command every 0.1 s; every other one stamped by the stage itself."""

    def __init__(self) -> None:
        self.next_s = 0.1
        self.ticks = 0

    def next_tick_s(self) -> float | None:
        return self.next_s

    def tick(self, now_s: float) -> list[Output]:
        self.next_s += 0.1
        self.ticks += 1
        own_stamp = stamp_ns(now_s) - 5 if self.ticks % 2 else 0
        header = Header(stamp_ns=own_stamp, seq=99, frame_id="base_link", source="ignored")
        command = WheelCommand(header=header, speed_m_s=0.1 * self.ticks, yaw_rate_rad_s=0.0)
        return [(topics.WHEEL_COMMAND, command)]


class _Stopper(Stage):
    """Answers every wheel command with a stop naming its speed."""

    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        assert isinstance(msg, WheelCommand)
        return [(topics.STOP, Stop(header=Header(), reason=f"{msg.speed_m_s:.1f}"))]


def _run(serialise: bool) -> list[tuple[float, str, Message]]:
    runner = LockstepRunner(
        [Node("ticker", _Ticker()), Node("stopper", _Stopper(), (topics.WHEEL_COMMAND,))],
        serialise=serialise,
    )
    seen: list[tuple[float, str, Message]] = []
    runner.observe(lambda t, topic, msg: seen.append((t, topic, msg)))
    runner.run_until(0.55)
    return seen


def test_publishing_stamps_seq_source_and_missing_stamps() -> None:
    seen = _run(serialise=True)
    commands = [(t, msg) for t, topic, msg in seen if topic == topics.WHEEL_COMMAND]
    stops = [(t, msg) for t, topic, msg in seen if topic == topics.STOP]
    assert len(commands) == len(stops) == 5
    for seq, (t, msg) in enumerate(commands):
        own = seq % 2 == 0  # the stage stamped ticks 1, 3, 5 itself
        want_stamp = stamp_ns(t) - 5 if own else stamp_ns(t)
        assert msg.header == Header(
            stamp_ns=want_stamp, seq=seq, frame_id="base_link", source="ticker"
        )
    for seq, (t, msg) in enumerate(stops):
        assert msg.header == Header(stamp_ns=stamp_ns(t), seq=seq, frame_id="", source="stopper")


def test_serialising_or_not_gives_the_same_messages() -> None:
    wired, direct = _run(serialise=True), _run(serialise=False)
    assert [(t, topic) for t, topic, _ in wired] == [(t, topic) for t, topic, _ in direct]
    assert [msg.to_wire() for *_, msg in wired] == [msg.to_wire() for *_, msg in direct]
    assert [msg.header for *_, msg in wired] == [msg.header for *_, msg in direct]
    speeds = [msg.speed_m_s for *_, msg in wired if isinstance(msg, WheelCommand)]
    np.testing.assert_allclose(speeds, [0.1, 0.2, 0.3, 0.4, 0.5])
