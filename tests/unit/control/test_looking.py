"""Looking before going: the vehicle stands while a head that pans looks round, and turns
round on the spot only for a head that does not (agent.control.controller)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from agent.arrays import FloatArray
from agent.control.controller import Controller, ControllerSettings, ControlOutput
from agent.task import Task
from tests.unit.control.test_safety import NO_LOOK, odometry, view

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


def _at(ctl: Controller, t: float, yaw: float, w: float = 0.0) -> None:
    ctl.update_odometry(t, np.array([0.0, 0.0, yaw]), np.eye(3) * 1e-6, 0.0, w)


def test_coming_to_park_the_head_is_asked_to_look_at_the_ring_the_turn_will_sweep() -> None:
    for goal, kind, expect in (((1.5, 0.0), "park", True), ((4.0, 0.0), "park", False),
                               ((1.5, 0.0), "goto", False)):  # fmt: skip
        yaw = 1.0 if kind == "park" else None
        ctl = Controller(Task(kind, goal, goal_yaw_rad=yaw), settings=NO_LOOK)
        _at(ctl, 0.1, 0.0)
        ctl.update_environment(view(0.1))
        ctl.command(0.1)
        radius = np.hypot(*(ctl.watch_xy - np.array(goal)).T)
        ring = np.abs(radius - (ctl.spec.circumradius_m - 0.05)) < 1e-9
        assert bool(ring.any()) == expect, (goal, kind)
        if expect:  # all round, 0.15 m or less apart
            angles = np.sort(np.arctan2(*(ctl.watch_xy[ring] - np.array(goal)).T[::-1]))
            gaps = np.diff(np.concatenate([angles, angles[:1] + 2.0 * np.pi]))
            assert gaps.max() * radius[ring][0] <= 0.15 + 1e-9


class _Boxed(Controller):
    """A controller whose braking envelope refuses any turn to the left once the heading
    is past ``left`` and to the right once it is past ``right`` (unknown space where a
    corner would sweep); straight motion is free."""

    left, right = 0.1, -math.inf

    def _admissible_scale(
        self, pose: FloatArray, v: float, w: float, tau: float, local: object = None
    ) -> float:
        refused = (w > 0.0 and pose[2] >= self.left) or (w < 0.0 and pose[2] <= self.right)
        return 0.0 if refused else 1.0


def _park_turn(ctl: Controller, steps: int) -> tuple[list[ControlOutput], float, float]:
    """Commands every 0.05 s of ``ctl`` parking on the spot where it stands, its odometry
    following them exactly: (commands, x, heading) at the end."""
    x = yaw = 0.0
    outs = []
    for k in range(1, steps + 1):
        t = 0.05 * k
        ctl.update_odometry(t, np.array([x, 0.0, yaw]), np.eye(3) * 1e-6, 0.0, 0.0)
        if k % 2 == 0:
            ctl.update_environment(view(t))
        out = ctl.command(t)
        outs.append(out)
        x += out.speed_m_s * math.cos(yaw) * 0.05
        yaw += out.yaw_rate_rad_s * 0.05
    return outs, x, yaw


def test_a_turn_blocked_the_short_way_goes_on_the_long_way_and_does_not_rock() -> None:
    ctl = _Boxed(Task("park", (0.0, 0.0), goal_yaw_rad=1.0), settings=NO_LOOK)
    outs, _, yaw = _park_turn(ctl, 60)
    rates = [o.yaw_rate_rad_s for o in outs]
    first_right = next(i for i, w in enumerate(rates) if w < 0.0)
    assert any(w > 0.0 for w in rates[:first_right])  # the short way first, till blocked
    # Then the long way round, though the short way opens again as it turns back.
    assert all(w < 0.0 for w in rates[first_right:])
    assert yaw < -1.0


def test_a_park_turn_blocked_both_ways_backs_off_and_looks() -> None:
    ctl = _Boxed(Task("park", (0.0, 0.0), goal_yaw_rad=1.0), settings=NO_LOOK)
    ctl.right = -0.1
    outs, x, _ = _park_turn(ctl, 80)
    reasons = [o.reason for o in outs]
    blocked = reasons.index("blocked")
    assert "backing" in reasons[blocked:] and x < -0.1
    assert "looking" in reasons[reasons.index("backing") :]
