"""The closed loop with live processes: the vehicle stops on stale data, end to end."""

from __future__ import annotations

import os
import signal
import time

import pytest

from agent.runtime import topics
from agent.runtime.messages import WheelCommand, decode
from tests.system.conftest import RunningGraph, child_pid, wait_for
from tests.system.test_launch import Launch, listening

pytestmark = pytest.mark.timeout(150)

STOP_WITHIN_S = 0.5  # the bound, from the fault to a zero wheel command


def _moving(command: WheelCommand) -> bool:
    return abs(command.speed_m_s) > 0.02 or abs(command.yaw_rate_rad_s) > 0.05


def _wait_until_driving(graph: RunningGraph, timeout_s: float = 60.0) -> None:
    with listening((graph.endpoint("vehicle"), topics.WHEEL_COMMAND)) as bus:
        deadline = time.monotonic() + timeout_s
        driving = 0
        while time.monotonic() < deadline and driving < 5:
            for _, payload in bus.poll(0.05):
                msg = decode(payload)
                driving = driving + 1 if isinstance(msg, WheelCommand) and _moving(msg) else 0
        if driving < 5:
            pytest.fail(f"the vehicle did not drive off within {timeout_s:g} s")


@pytest.mark.slow
@pytest.mark.parametrize(
    ("victim", "sig"),
    [("planner", signal.SIGKILL), ("planner", signal.SIGSTOP), ("tracking", signal.SIGKILL)],
)
def test_the_vehicle_stops_when_the_agent_dies_or_hangs(
    launch: Launch, victim: str, sig: int
) -> None:
    """The demo graph driving; one of the agent's processes is killed (or stopped: alive but
    silent) while the vehicle moves. The vehicle controller's wheel command is zero within
    0.5 s of the fault (the environment vector goes stale 0.3 s after its stamp), and stays
    zero until fresh, trusted vectors come again (the launcher replaces the process)."""
    graph = launch("launch/demo.toml")
    _wait_until_driving(graph)
    pid = wait_for(lambda: child_pid(graph.runtime_dir, victim), 5, f"{victim}'s pid")
    with listening((graph.endpoint("vehicle"), topics.WHEEL_COMMAND)) as bus:
        bus.poll(0.2)  # connected, the queue drained
        os.kill(pid, sig)
        faulted = time.monotonic()
        stopped_at = None
        while time.monotonic() - faulted < 3.0 and stopped_at is None:
            for _, payload in bus.poll(0.01):
                msg = decode(payload)
                if isinstance(msg, WheelCommand) and not _moving(msg) and msg.speed_m_s == 0.0:
                    stopped_at = time.monotonic()
                    break
        assert stopped_at is not None, "the wheel command never went to zero"
        stop_s = stopped_at - faulted
        # Then it stays zero while the agent is down (a stopped process is replaced only
        # after 2 s without heartbeats; a killed one may be back sooner): 0.5 s of commands.
        held = []
        until = time.monotonic() + (0.5 if sig == signal.SIGSTOP else 0.0)
        while time.monotonic() < until:
            held += [decode(p) for _, p in bus.poll(0.02)]
    if sig == signal.SIGSTOP:
        os.kill(pid, signal.SIGCONT)
    assert stop_s <= STOP_WITHIN_S, stop_s
    commands = [m for m in held if isinstance(m, WheelCommand)]
    assert not any(_moving(m) for m in commands)
    assert sig != signal.SIGSTOP or len(commands) >= 5
    graph.stop()
