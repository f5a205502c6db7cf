"""Looking before going: the vehicle stands while a head that pans looks round, and turns
round on the spot only for a head that does not (agent.control.controller)."""

from __future__ import annotations

import dataclasses

import numpy as np

from agent.control.controller import Controller, ControllerSettings, ControlOutput
from agent.task import Task
from tests.unit.control.test_safety import odometry, view

SETTINGS = ControllerSettings()


def _start(pan_rad: float, until_s: float) -> list[ControlOutput]:
    """The commands every 0.05 s up to ``until_s`` of a controller at the origin facing its
    goal 5 m ahead, each vector's scanned window 40° wide about ``pan_rad``; the odometry
    does not move (so only the commands show what it meant to do)."""
    ctl = Controller(Task("goto", (5.0, 0.0)))
    outs = []
    for k in range(1, round(until_s / 0.05) + 1):
        t = 0.05 * k
        odometry(ctl, t)
        if k % 2 == 0:
            window = np.array([pan_rad - 0.35, pan_rad + 0.35])
            ctl.update_environment(dataclasses.replace(view(t), scan_window_rad=window))
        outs.append(ctl.command(t))
    return outs


def test_with_a_head_that_pans_the_vehicle_stands_then_goes_without_turning_round() -> None:
    outs = _start(1.2, SETTINGS.look_stand_s + 1.0)
    standing = [o for o in outs if o.reason == "looking"]
    assert len(standing) >= round(SETTINGS.look_stand_s / 0.05) - 2
    assert all(o.speed_m_s == 0.0 and o.yaw_rate_rad_s == 0.0 for o in standing)
    # While it stands, the head is told the way: toward the goal.
    assert len(standing[0].intent_xy) and standing[0].intent_xy[-1][0] > 1.0
    after = outs[len(standing) + 1 :]
    assert after and all(o.reason != "looking" for o in after)
    assert any(o.speed_m_s > 0.0 for o in after)


def test_with_a_head_fixed_ahead_the_vehicle_turns_round_after_standing() -> None:
    outs = _start(0.0, SETTINGS.look_stand_s + 1.0)
    late = outs[round(SETTINGS.look_stand_s / 0.05) + 2 :]
    assert late and all(o.reason == "looking" for o in late)
    assert all(o.yaw_rate_rad_s > 0.0 for o in late[1:])
