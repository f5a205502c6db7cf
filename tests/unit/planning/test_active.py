"""The active planner: its cost model against the head's own pan axis, the look memory, the
candidate actions, and what it chooses in situations whose answer is known."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from agent.errors import ConfigError
from agent.planning.active import (
    ActivePolicy,
    ActiveSettings,
    GreedyPolicy,
    HeadTiming,
    LookMemory,
    Situation,
    candidate_actions,
    feature_sigma_m,
)
from agent.planning.policies import HeadLimits, HeadView, make_policy
from agent.sensor.params import nominal_sensor
from agent.stages.head_stage import PanAxis


@pytest.mark.parametrize("degrees", [1.0, 10.0, 45.0, 60.0, 90.0, 180.0])
def test_slew_time_is_the_head_axis_time_to_settle(degrees: float) -> None:
    sensor = nominal_sensor()
    timing = HeadTiming.of(sensor)
    axis = PanAxis(sensor.pan_rate_limit_rad_s, sensor.pan_acceleration_limit_rad_s2)
    axis.target_rad = math.radians(degrees)
    t = 0.0
    while not axis.settled:
        axis.advance(1e-3)
        t += 1e-3
        assert t < 5.0
    # The axis is stepped in 1 ms: it settles within a step of the profile's time.
    assert float(timing.slew_s(math.radians(degrees))) == pytest.approx(t, abs=1.5e-3)


def test_sweep_time_is_the_mirrors() -> None:
    timing = HeadTiming.of(nominal_sensor())
    assert float(timing.sweep_s(math.radians(40.0))) == pytest.approx(0.1)
    assert float(timing.sweep_s(math.radians(20.0))) == pytest.approx(0.05)


def test_candidate_actions_are_all_within_the_head() -> None:
    limits = HeadLimits()
    actions = candidate_actions(limits, math.radians(5.0), (math.radians(40.0), math.radians(20.0)))
    assert actions.shape == (37 * 4, 3)  # 37 pans; the full window and three half windows
    assert np.all(np.abs(actions[:, 0]) <= limits.pan_limit_rad + 1e-12)
    assert np.all(actions[:, 1] >= -limits.scan_half_angle_rad - 1e-12)
    assert np.all(actions[:, 2] <= limits.scan_half_angle_rad + 1e-12)
    assert np.all(actions[:, 1] < actions[:, 2])
    with pytest.raises(ConfigError, match="window width"):
        candidate_actions(limits, math.radians(5.0), (math.radians(50.0),))
    with pytest.raises(ConfigError, match="pan step"):
        candidate_actions(limits, 0.0, (math.radians(40.0),))


def test_settings_refuse_nonsense() -> None:
    with pytest.raises(ConfigError, match="stale_tau_s"):
        ActiveSettings(stale_tau_s=0.0)
    with pytest.raises(ConfigError, match="near_weight"):
        ActiveSettings(near_weight=-1.0)


def test_feature_sigma_follows_table_1() -> None:
    sensor = nominal_sensor()
    # Table 1 of the chapter: 2.547 cm at 2.0 m, 7.66 cm at 2.5 m (eq. 6.19-6.20 is z⁴; the
    # table's far end is above it, the measured noise density being above theory there).
    s = feature_sigma_m(np.array([1.0, 2.0, 2.5]), sensor, 0.0)
    assert s[0] == pytest.approx(0.00148, rel=0.05)
    assert s[1] == pytest.approx(0.02547, rel=0.1)
    assert s[2] < 0.0766
    assert feature_sigma_m(np.array([0.5]), sensor, 0.003)[0] == 0.003


def test_look_memory_marks_the_wedge_and_follows_the_vehicle() -> None:
    mem = LookMemory(cell_m=0.1, size_m=8.0)
    mem.add_wedge(1.0, np.array([0.0, 0.0]), -0.35, 0.35, 0.4, 2.5)
    xs, ys = mem.centres()

    def at(x: float, y: float) -> float:
        return float(mem.last_s[np.searchsorted(ys, y) - 0, np.searchsorted(xs, x)])

    assert at(1.5, 0.02) == 1.0
    assert at(0.15, 0.02) == -np.inf  # nearer than the depth of field
    assert at(0.02, 1.5) == -np.inf  # beside the window
    assert at(-1.5, 0.02) == -np.inf  # behind
    # The grid moves with the vehicle; what was seen stays where it was in odom.
    mem.recentre(np.array([2.5, 0.0]))
    xs, ys = mem.centres()
    assert at(1.5, 0.02) == 1.0
    assert xs[0] == pytest.approx(2.5 - 4.0 + 0.05)


def _situation(intent: list[list[float]]) -> Situation:
    return Situation(
        pose=np.array([0.0, 0.0, 0.0]), speed_m_s=0.3, intent_xy=np.asarray(intent, float)
    )


def test_active_looks_where_the_path_turns_when_ahead_is_known() -> None:
    policy = ActivePolicy()
    sit = _situation([[0.6, 0.2], [1.0, 1.0], [1.0, 2.5]])
    # Ahead was just scanned; the path's turn to the left never was.
    sit.memory.add_wedge(10.0, np.array([0.3, 0.0]), -0.35, 0.35, 0.4, 2.5)
    decision = policy.decide(sit, 0.0, 10.05)
    assert math.degrees(decision.target.pan_rad) > 30.0
    sit_right = _situation([[0.6, -0.2], [1.0, -1.0], [1.0, -2.5]])
    sit_right.memory.add_wedge(10.0, np.array([0.3, 0.0]), -0.35, 0.35, 0.4, 2.5)
    right = policy.decide(sit_right, 0.0, 10.05).target
    # Its window's right part, where open space is vouched for (unvouched_left_deg), on the
    # turn; the left 15° of it are not counted.
    assert math.degrees(right.pan_rad) < -20.0
    assert math.degrees(right.pan_rad + right.window_low_rad) < -40.0


def test_only_the_window_s_vouching_part_counts_for_space() -> None:
    # All seen just now but the bearings 6-19° left of ahead. The head's window, where it is
    # now, spans them, but in its left 15°, where a scan that returns nothing vouches for
    # nothing (unvouched_left_deg): the head pans left to bring them into its right part.
    def decide(settings: ActiveSettings) -> float:
        sit = _situation([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
        head = np.array([0.3, 0.0])
        sit.memory.add_wedge(10.0, head, -math.pi, math.radians(5.5), 0.4, 2.5)
        sit.memory.add_wedge(10.0, head, math.radians(19.5), math.pi, 0.4, 2.5)
        return math.degrees(ActivePolicy(settings).decide(sit, 0.0, 10.05).target.pan_rad)

    assert decide(dataclasses.replace(ActiveSettings(), unvouched_left_deg=0.0)) == 0.0
    assert decide(ActiveSettings()) >= 10.0


def test_active_looks_where_the_vehicle_asks() -> None:
    # A vehicle waiting beside a walk: its way ahead just seen, its left 3 s ago, its
    # right long ago. Not asked, the head looks right, where the space is stalest; asked to
    # look at the places on its left where a walker it lost may be (watch_xy), it looks
    # there.
    def decide(watch: list[list[float]]) -> float:
        sit = _situation([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
        head = np.array([0.3, 0.0])
        sit.memory.add_wedge(10.0, head, -math.pi, math.pi, 0.4, 2.5)
        sit.memory.add_wedge(17.0, head, 0.35, math.pi, 0.4, 2.5)
        sit.memory.add_wedge(19.95, head, -0.35, 0.35, 0.4, 2.5)
        sit.watch_xy = np.asarray(watch, dtype=np.float64).reshape(-1, 2)
        return math.degrees(ActivePolicy().decide(sit, 0.0, 20.0).target.pan_rad)

    assert decide([]) < -20.0
    places = [[0.8, 0.4 + 0.1 * k] for k in range(20)]  # a walk across the way, to the left
    assert decide(places) > 20.0


def test_active_with_no_intent_protects_the_direction_of_motion() -> None:
    policy = ActivePolicy()
    sit = Situation(pose=np.array([0.0, 0.0, 0.0]), speed_m_s=0.4)
    # Nothing seen yet, the head panned 60° left: within a few decisions (each followed by
    # the sweep it chose, as the planner stage records it) it looks where the vehicle goes.
    pan, now, ahead = math.radians(60.0), 5.0, False
    for _ in range(4):
        t = policy.decide(sit, pan, now).target
        sit.memory.add_wedge(
            now, np.array([0.3, 0.0]), t.pan_rad + t.window_low_rad,
            t.pan_rad + t.window_high_rad, 0.4, 2.5,
        )  # fmt: skip
        pan, now = t.pan_rad, now + 0.3
        if t.pan_rad + t.window_low_rad <= 0.0 <= t.pan_rad + t.window_high_rad:
            ahead = True
            break
    assert ahead


def _all_seen(sit: Situation, t_s: float) -> None:
    """Space everywhere round the vehicle freshly scanned at ``t_s``: only tracks are
    worth a look."""
    for lo in np.arange(-math.pi, math.pi, 0.5):
        sit.memory.add_wedge(t_s, np.array([0.3, 0.0]), lo, lo + 0.5, 0.4, 2.5)


def test_active_prefers_a_path_relevant_track() -> None:
    policy = ActivePolicy(ActiveSettings(near_weight=0.0))
    sit = _situation([[1.0, 0.0], [3.0, 0.0]])
    _all_seen(sit, 10.0)
    sit.position_xy = np.array([[1.2, 1.2], [1.2, -0.3]])  # off the path at 45°; on it
    sit.velocity_xy = np.zeros((2, 2))
    sit.covariance = np.array([np.eye(2) * 0.01, np.eye(2) * 0.01])
    sit.ends_xy = np.repeat(sit.position_xy[:, None], 2, axis=1)
    d = policy.decide(sit, 0.0, 10.0)
    t = d.target
    bearing = math.atan2(-0.3, 1.2 - 0.3)
    assert t.pan_rad + t.window_low_rad <= bearing <= t.pan_rad + t.window_high_rad
    assert d.track_bits > 0


def test_an_already_certain_track_is_not_revisited() -> None:
    # Two tracks beside the path, one known to 2 mm, one to 10 cm: the planner looks at the
    # uncertain one. The certain one alone is worth next to nothing: below ``track_need_m``
    # (1 cm) a look changes nothing the vehicle uses (it inflates obstacles by 3σ).
    policy = ActivePolicy(ActiveSettings(near_weight=0.0, path_near_weight=0.0))
    sit = _situation([[1.0, 0.0], [3.0, 0.0]])
    _all_seen(sit, 10.0)
    sit.position_xy = np.array([[1.2, 0.8], [1.2, -0.8]])
    sit.velocity_xy = np.zeros((2, 2))
    sit.covariance = np.array([np.eye(2) * 0.002**2, np.eye(2) * 0.1**2])
    sit.ends_xy = np.repeat(sit.position_xy[:, None], 2, axis=1)
    t = policy.decide(sit, 0.0, 10.0).target
    right = math.atan2(-0.8, 1.2 - 0.3)
    assert t.pan_rad + t.window_low_rad <= right <= t.pan_rad + t.window_high_rad
    sit.position_xy, sit.velocity_xy = sit.position_xy[:1], sit.velocity_xy[:1]
    sit.covariance, sit.ends_xy = sit.covariance[:1], sit.ends_xy[:1]
    assert policy.decide(sit, 0.0, 10.0).track_bits < 0.2
    sit.covariance = np.array([np.eye(2) * 0.1**2])
    assert policy.decide(sit, 0.0, 10.0).track_bits > 3.0


def test_a_wall_is_worth_a_look_only_across_its_line() -> None:
    # A wall beside the path, 1.4 m of it seen: its midpoint may lie anywhere along it
    # (30 cm, 1σ) but no look at a plain wall can tell where; across its line it is known
    # to 3 mm. Its bits are those of the across-line σ (``line_sigma_m``) alone: not worth
    # a look; known across to 5 cm, it is.
    policy = ActivePolicy(ActiveSettings(near_weight=0.0, path_near_weight=0.0))
    sit = _situation([[1.0, 0.0], [3.0, 0.0]])
    _all_seen(sit, 10.0)
    sit.position_xy = np.array([[1.5, -0.8]])
    sit.velocity_xy = np.zeros((1, 2))
    sit.covariance = np.array([np.diag([0.3**2, 0.003**2])])
    sit.ends_xy = np.array([[[0.8, -0.8], [2.2, -0.8]]])
    assert policy.decide(sit, 0.0, 10.0).track_bits > 3.0  # taken for a point: 30 cm to gain
    sit.line_sigma_m = np.array([0.003])
    assert policy.decide(sit, 0.0, 10.0).track_bits < 0.2
    sit.line_sigma_m = np.array([0.0])  # known exactly: nothing to gain
    assert policy.decide(sit, 0.0, 10.0).track_bits == 0.0
    sit.line_sigma_m = np.array([0.05])
    assert policy.decide(sit, 0.0, 10.0).track_bits > 1.0


def test_greedy_goes_for_the_most_uncertain_track_whatever_the_path() -> None:
    policy = GreedyPolicy()
    sit = _situation([[1.0, 0.0], [3.0, 0.0]])
    sit.position_xy = np.array([[0.3, 1.5], [1.5, 0.0]])
    sit.velocity_xy = np.zeros((2, 2))
    sit.covariance = np.array([np.eye(2) * 0.04, np.eye(2) * 0.0001])
    sit.ends_xy = np.repeat(sit.position_xy[:, None], 2, axis=1)
    d = policy.decide(sit, 0.0, 1.0)
    assert math.degrees(d.target.pan_rad) > 60.0


def test_a_decision_waits_for_a_sweep_at_the_target() -> None:
    policy = make_policy("active", HeadLimits())
    sit = _situation([[1.0, 1.0], [1.0, 2.5]])

    def head(sweeps: int, pan: float, settled: bool = True) -> HeadView:
        return HeadView(0.1 * sweeps, pan, pan, -0.35, 0.35, settled, sweeps, True, True)

    first = policy.choose(None, 0.0, sit)  # no head yet: the first decision
    assert policy.decisions == 1
    # Slewing there: no new decision until settled and one sweep done.
    assert policy.choose(head(3, 0.0, settled=False), 0.3, sit) == first
    if abs(first.pan_rad) > 1e-9:
        assert policy.choose(head(4, first.pan_rad), 0.4, sit) == first
        assert policy.decisions == 1
        policy.choose(head(5, first.pan_rad), 0.5, sit)
        assert policy.decisions == 2
    # The passive policies take the situation and ignore it.
    forward = make_policy("forward", HeadLimits())
    assert forward.choose(None, 0.0, sit).pan_rad == 0.0


def test_a_turning_vehicle_carries_the_window_round() -> None:
    # The path's unknown stretch is 60° to the left of the heading now; the vehicle turns
    # left at 1 rad/s, so by the time a slew of 60° ends (0.58 s) it has turned 33°, and
    # the head needs less pan to look there than it would standing.
    standing = _situation([[0.6, 0.2], [1.0, 1.7], [1.0, 2.5]])
    standing.memory.add_wedge(10.0, np.array([0.3, 0.0]), -0.35, 0.35, 0.4, 2.5)
    turning = _situation([[0.6, 0.2], [1.0, 1.7], [1.0, 2.5]])
    turning.memory.add_wedge(10.0, np.array([0.3, 0.0]), -0.35, 0.35, 0.4, 2.5)
    turning.yaw_rate_rad_s = 1.0
    policy = ActivePolicy()
    still = policy.decide(standing, 0.0, 10.05).target.pan_rad
    moving = policy.decide(turning, 0.0, 10.05).target.pan_rad
    assert 0.0 < moving < still


def test_maintained_are_the_obstacles_near_the_path() -> None:
    policy = ActivePolicy()
    sit = _situation([[1.0, 0.0], [3.0, 0.0]])
    # On the path; 1.2 m beside it (within the corridor's 0.55 m and 1 m more); 3 m off;
    # 3 m off but walking onto the path.
    sit.position_xy = np.array([[1.5, 0.0], [1.5, 1.2], [1.5, 3.0], [2.0, 3.0]])
    sit.velocity_xy = np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, -1.0]])
    sit.covariance = np.array([np.eye(2) * 0.01] * 4)
    sit.ends_xy = np.repeat(sit.position_xy[:, None], 2, axis=1)
    assert policy.maintained(sit).tolist() == [1, 1, 0, 1]
    assert policy.maintained(Situation()).shape == (0,)


def test_look_memory_forgets_all_after_a_jump_beyond_its_size() -> None:
    mem = LookMemory(cell_m=0.1, size_m=8.0)
    mem.add_wedge(1.0, np.array([0.0, 0.0]), -0.35, 0.35, 0.4, 2.5)
    mem.recentre(np.array([20.0, -15.0]))  # odometry reset or a long gap: nothing carries
    assert not np.isfinite(mem.last_s).any()
