"""Tests of the graph's stages, the lock-step runner and the process shell, without sockets.

The pan axis against its trapezoidal profile; the head stage's sweeps, windows, refusals,
laser safety and watchdog; the world stage's exact motion, timeout, clamping and rate; the
calibration stage; the lock-step runner's determinism and wire encoding; and the process
shell driven by a fake bus and a fake clock.
"""

from __future__ import annotations

import functools
import itertools
import logging
import math
from collections import deque
from pathlib import Path

import msgpack
import numpy as np
import numpy.typing as npt
import pytest

from agent.calibration.table import Calibration
from agent.kinematics.trajectory import ConstantTwist
from agent.runtime import topics
from agent.runtime.launch import parse_launch
from agent.runtime.lockstep import LockstepRunner, Node
from agent.runtime.messages import (
    CalibratedScan,
    HeadCommand,
    Header,
    HeadState,
    Heartbeat,
    Message,
    RawScan,
    Stop,
    WheelCommand,
    WorldTruth,
    decode,
    stamp_ns,
)
from agent.runtime.stage import Output
from agent.sensor.params import SensorParameters
from agent.sim.simulator import ScanTruth, SensorSimulator
from agent.sim.targets import head_centred_pose, plane_world
from agent.sim.world import World
from agent.sim.world_file import load_world
from agent.stages.calibration_stage import CalibrationStage
from agent.stages.head_stage import IDLE_STATE_PERIOD_S, HeadStage, PanAxis
from agent.stages.world_stage import WorldStage
from processes.launcher import PublishedStats, TopicStats
from processes.runtime import CATCH_UP_S, FAULT_AFTER, MAX_POLL_S, ProcessShell

pytestmark = pytest.mark.filterwarnings("error")

REPO = Path(__file__).resolve().parents[3]
BOX_WORLD = REPO / "worlds" / "box_before_wall.toml"
SIM_LAUNCH = REPO / "launch" / "sim.toml"
FloatArray = npt.NDArray[np.float64]

PAN_STEP_S = 1e-3  # the pan axis's integration step for whole-millisecond durations
PAN_TOLERANCE_RAD = 1e-4


@pytest.fixture(scope="module")
def box_world() -> World:
    return load_world(BOX_WORLD)


def _outputs(outputs: list[Output], topic: str) -> list[Message]:
    return [msg for t, msg in outputs if t == topic]


def _only(outputs: list[Output], topic: str) -> Message:
    found = _outputs(outputs, topic)
    assert len(found) == 1, f"expected one {topic}, got {[t for t, _ in outputs]}"
    return found[0]


def _head_command(
    head: SensorParameters,
    pan_rad: float = 0.0,
    window_deg: tuple[float, float] | None = None,
    laser: bool = True,
    seq: int = 0,
) -> HeadCommand:
    if window_deg is None:
        low, high = -head.scan_half_angle_rad, head.scan_half_angle_rad
    else:
        low, high = math.radians(window_deg[0]), math.radians(window_deg[1])
    return HeadCommand(
        header=Header(seq=seq),
        pan_rad=pan_rad,
        window_low_rad=low,
        window_high_rad=high,
        laser=laser,
    )


def _tick_due(stage: HeadStage | WorldStage) -> tuple[float, list[Output]]:
    """Tick the stage at the time it asked for."""
    due = stage.next_tick_s()
    assert due is not None
    return due, stage.tick(due)


# ============================================================================================
# PanAxis
# ============================================================================================
def _profile_time(distance_rad: float, head: SensorParameters) -> float:
    """Duration of the time-optimal rest-to-rest move (triangular or trapezoidal profile)."""
    rate, accel = head.pan_rate_limit_rad_s, head.pan_acceleration_limit_rad_s2
    d = abs(distance_rad)
    if d >= rate * rate / accel:  # reaches the rate limit: accelerate, coast, brake
        return d / rate + rate / accel
    return 2.0 * math.sqrt(d / accel)  # triangular: accelerate then brake


def _move(
    head: SensorParameters, target: float, start: float = 0.0, duration_s: float = 1.5
) -> tuple[PanAxis, FloatArray, FloatArray]:
    axis = PanAxis(
        head.pan_rate_limit_rad_s,
        head.pan_acceleration_limit_rad_s2,
        position_rad=start,
        target_rad=target,
    )
    t, p = axis.advance(duration_s)
    return axis, t, p


def _rates(t: FloatArray, p: FloatArray) -> FloatArray:
    return np.diff(p) / np.diff(t)


def _accelerations(t: FloatArray, p: FloatArray) -> FloatArray:
    dt = float(t[1] - t[0])
    np.testing.assert_allclose(np.diff(t), dt, rtol=1e-9)
    return np.diff(p, 2) / dt**2


def _settle_time(t: FloatArray, p: FloatArray, target: float) -> float:
    """The first time from which the axis stays on the target."""
    off = np.flatnonzero(np.abs(p - target) >= PAN_TOLERANCE_RAD)
    assert off.size < t.size - 1, "never settled"
    return float(t[off[-1] + 1]) if off.size else 0.0


# Grid-aligned moves: the profile's switching times fall on whole integration steps.
ALIGNED_TARGETS = [
    pytest.param(math.pi / 2, id="trapezoid-90deg"),  # 0.25 s accelerate, coast, brake
    pytest.param(math.pi / 16, id="triangle-11.25deg"),  # 0.125 s accelerate, brake
]
GENERIC_TARGETS = [0.1, 0.3, 0.7, -1.5]
OVERSHOOT_REASON = (
    "PanAxis._step decides to brake from the error *before* the step (|error| <= v²/2a), so "
    "braking starts up to one step late: the axis passes the target still moving (~0.2 rad/s "
    "for a 0.3 rad move), overshoots by 1.5-6 mrad (tolerance 0.1 mrad), comes back, and "
    "settles 20-50 ms after the trapezoidal profile's end"
)
SNAP_REASON = (
    "PanAxis._step's settle snap (|error| < 1e-4 rad and |v| <= a·dt -> position := target) "
    "jumps up to 1e-4 rad in one 1 ms step after the overshoot: a second difference of "
    "positions up to ~8x the acceleration limit"
)


@pytest.mark.parametrize("target", [math.pi / 2, math.pi / 16, *GENERIC_TARGETS, -0.02])
def test_pan_axis_never_exceeds_its_rate_limit(head: SensorParameters, target: float) -> None:
    _, t, p = _move(head, target)
    assert np.max(np.abs(_rates(t, p))) <= head.pan_rate_limit_rad_s * (1 + 1e-9)


@pytest.mark.parametrize("target", [math.pi / 2, math.pi / 16, *GENERIC_TARGETS, -0.02])
def test_pan_axis_respects_its_acceleration_limit_away_from_the_target(
    head: SensorParameters, target: float
) -> None:
    """Every step of the move, the last ones included."""
    _, t, p = _move(head, target)
    acc = _accelerations(t, p)
    away = np.abs(p - target) >= PAN_TOLERANCE_RAD
    clear = away[:-2] & away[1:-1] & away[2:]
    assert clear.sum() > 10
    assert np.max(np.abs(acc[clear])) <= head.pan_acceleration_limit_rad_s2 * (1 + 1e-6)


@pytest.mark.parametrize("target", ALIGNED_TARGETS)
def test_pan_axis_follows_the_trapezoidal_profile_on_aligned_moves(
    head: SensorParameters, target: float
) -> None:
    axis, t, p = _move(head, target)
    rate, accel = head.pan_rate_limit_rad_s, head.pan_acceleration_limit_rad_s2
    assert np.max(np.abs(_rates(t, p))) <= rate * (1 + 1e-9)
    assert np.max(np.abs(_accelerations(t, p))) <= accel * (1 + 1e-6)
    assert np.max(p - target) <= PAN_TOLERANCE_RAD  # no overshoot
    assert np.all(np.diff(p) >= 0)  # never backs up
    assert axis.settled and axis.rate_rad_s == 0.0 and axis.position_rad == target
    expected = _profile_time(target, head)
    assert abs(_settle_time(t, p, target) - expected) <= 5 * PAN_STEP_S


@pytest.mark.parametrize("target", GENERIC_TARGETS)
def test_pan_axis_arrives_without_overshoot_in_the_profile_time(
    head: SensorParameters, target: float
) -> None:
    axis, t, p = _move(head, target)
    assert axis.settled and axis.rate_rad_s == 0.0
    overshoot = float(np.max((p - target) * math.copysign(1.0, target)))
    assert overshoot <= PAN_TOLERANCE_RAD
    assert abs(_settle_time(t, p, target) - _profile_time(target, head)) <= 5 * PAN_STEP_S


@pytest.mark.parametrize("target", [0.3, -1.5])
def test_pan_axis_settles_within_its_acceleration_limit(
    head: SensorParameters, target: float
) -> None:
    _, t, p = _move(head, target)
    assert np.max(np.abs(_accelerations(t, p))) <= head.pan_acceleration_limit_rad_s2 * (1 + 1e-6)


def test_pan_axis_handles_a_target_reversed_mid_move(head: SensorParameters) -> None:
    rate, accel = head.pan_rate_limit_rad_s, head.pan_acceleration_limit_rad_s2
    axis = PanAxis(rate, accel, target_rad=1.0)
    t1, p1 = axis.advance(0.2)
    v0 = axis.rate_rad_s
    assert v0 == pytest.approx(accel * 0.2, rel=1e-6)  # still accelerating
    axis.target_rad = -0.5
    t2, p2 = axis.advance(1.5)
    t = np.concatenate([t1, t1[-1] + t2[1:]])
    p = np.concatenate([p1, p2[1:]])
    assert np.max(np.abs(_rates(t, p))) <= rate * (1 + 1e-9)
    acc = _accelerations(t, p)
    away = np.abs(p + 0.5) >= PAN_TOLERANCE_RAD
    clear = away[:-2] & away[1:-1] & away[2:]
    assert np.max(np.abs(acc[clear])) <= accel * (1 + 1e-6)
    # It cannot turn at once: it goes on, braking, for v/a, about v²/2a further.
    peak = int(np.argmax(p))
    assert t[peak] == pytest.approx(0.2 + v0 / accel, abs=3 * PAN_STEP_S)
    assert p[peak] == pytest.approx(p1[-1] + v0**2 / (2 * accel), abs=5e-3)
    assert axis.settled and axis.rate_rad_s == 0.0
    assert axis.position_rad == pytest.approx(-0.5, abs=PAN_TOLERANCE_RAD)


def test_a_settled_pan_axis_stays_put(head: SensorParameters) -> None:
    axis = PanAxis(
        head.pan_rate_limit_rad_s,
        head.pan_acceleration_limit_rad_s2,
        position_rad=0.4,
        target_rad=0.4,
    )
    assert axis.settled
    t, p = axis.advance(0.5)
    assert t[0] == 0.0 and t[-1] == 0.5
    assert np.all(p == 0.4) and axis.rate_rad_s == 0.0 and axis.settled
    # And after a move, too.
    axis.target_rad = math.pi / 16
    axis.advance(1.0)
    _, p = axis.advance(0.3)
    assert np.all(p == math.pi / 16) and axis.rate_rad_s == 0.0


# ============================================================================================
# HeadStage
# ============================================================================================
def test_head_start_then_tick_gives_a_full_raw_scan_and_its_state(
    box_world: World, head: SensorParameters
) -> None:
    stage = HeadStage(box_world, seed=1)
    started = stage.start(0.0)
    state = _only(started, topics.HEAD_STATE)
    assert isinstance(state, HeadState)
    assert state.laser_on and state.mode == "scanning" and state.sweeps == 0
    assert state.command_seq == -1 and state.command_accepted
    due, out = _tick_due(stage)
    assert due == pytest.approx(head.sweep_period_s)
    assert [t for t, _ in out] == [topics.RAW_SCAN, topics.HEAD_STATE]
    raw = _only(out, topics.RAW_SCAN)
    assert isinstance(raw, RawScan)
    assert raw.time_s.size == head.samples_per_sweep == 256
    assert raw.sweep_index == 0 and raw.direction == 1
    assert np.all((raw.time_s > 0.0) & (raw.time_s < due))
    assert np.all(np.abs(raw.mirror_angle_rad) <= head.scan_half_angle_rad + 1e-3)
    assert raw.header.stamp_ns == stamp_ns(float(raw.time_s[-1]))
    # The box and the wall are in view: the electrodes see signal.
    assert np.max(np.abs(raw.current_1_A) + np.abs(raw.current_2_A)) > 0
    state = _only(out, topics.HEAD_STATE)
    assert isinstance(state, HeadState)
    assert state.sweeps == 1 and state.header.stamp_ns == stamp_ns(due)
    decode(raw.to_wire(), expect=RawScan)  # a valid message on the wire


def test_head_sweeps_alternate_direction(box_world: World, head: SensorParameters) -> None:
    stage = HeadStage(box_world, seed=1)
    stage.start(0.0)
    scans, ticks = [], []
    for _ in range(4):
        due, out = _tick_due(stage)
        ticks.append(due)
        scans.append(_only(out, topics.RAW_SCAN))
    assert [s.direction for s in scans] == [1, -1, 1, -1]
    assert [s.sweep_index for s in scans] == [0, 1, 2, 3]
    np.testing.assert_allclose(np.diff(ticks), head.sweep_period_s, rtol=1e-9)
    for s in scans:
        assert np.all(np.sign(np.diff(s.mirror_angle_rad)) == s.direction)
    for before, after in itertools.pairwise(scans):
        assert after.time_s[0] > before.time_s[-1]  # back to back, in time order


def test_a_narrower_window_takes_effect_at_the_next_sweep(
    box_world: World, head: SensorParameters
) -> None:
    stage = HeadStage(box_world, seed=1)
    stage.start(0.0)
    _tick_due(stage)
    stage.handle(topics.HEAD_COMMAND, _head_command(head, window_deg=(-10, 10)), 0.15)
    due, out = _tick_due(stage)  # the sweep under way when the command came
    assert _only(out, topics.RAW_SCAN).time_s.size == 256
    state = _only(out, topics.HEAD_STATE)
    assert isinstance(state, HeadState)
    assert state.window_high_rad == pytest.approx(math.radians(10))
    ticks, sizes = [due], []
    for _ in range(3):
        due, out = _tick_due(stage)
        raw = _only(out, topics.RAW_SCAN)
        assert isinstance(raw, RawScan)
        ticks.append(due)
        sizes.append(raw.time_s.size)
        assert np.all(np.abs(raw.mirror_angle_rad) <= math.radians(10) + 1e-3)
    assert sizes == [128, 128, 128]  # half the width: half the samples
    np.testing.assert_allclose(np.diff(ticks), head.sweep_period_s / 2, rtol=1e-9)


@pytest.mark.parametrize(
    ("pan_deg", "window_deg", "limit"),
    [
        (95.0, None, "±90 deg"),
        (-91.0, None, "±90 deg"),
        (0.0, (-25.0, 10.0), "±20 deg"),
        (0.0, (-10.0, 21.0), "±20 deg"),
    ],
)
def test_commands_outside_the_limits_are_refused_until_a_valid_one(
    box_world: World,
    head: SensorParameters,
    pan_deg: float,
    window_deg: tuple[float, float] | None,
    limit: str,
) -> None:
    stage = HeadStage(box_world, seed=1)
    stage.start(0.0)
    _tick_due(stage)
    bad = _head_command(head, math.radians(pan_deg), window_deg, seq=7)
    state = _only(stage.handle(topics.HEAD_COMMAND, bad, 0.12), topics.HEAD_STATE)
    assert isinstance(state, HeadState)
    assert not state.command_accepted and state.command_seq == 7
    assert limit in state.command_message and "refused" in state.command_message
    assert not state.laser_on and state.mode != "scanning"
    assert state.target_pan_rad == 0.0  # the pan does not go there
    ticks = []
    for _ in range(3):
        due, out = _tick_due(stage)
        ticks.append(due)
        assert [t for t, _ in out] == [topics.HEAD_STATE]
        state = _only(out, topics.HEAD_STATE)
        assert isinstance(state, HeadState)
        assert not state.laser_on and not state.command_accepted
    assert ticks[0] == pytest.approx(0.12 + IDLE_STATE_PERIOD_S)
    np.testing.assert_allclose(np.diff(ticks), IDLE_STATE_PERIOD_S)
    good = _head_command(head, 0.0, (-10.0, 10.0), seq=8)
    state = _only(stage.handle(topics.HEAD_COMMAND, good, 0.5), topics.HEAD_STATE)
    assert isinstance(state, HeadState)
    assert state.command_accepted and state.laser_on and state.command_message == ""
    assert state.mode == "scanning"
    due, out = _tick_due(stage)
    assert due == pytest.approx(0.55)  # the new window at once: a 20° sweep
    assert _only(out, topics.RAW_SCAN).time_s.size == 128
    assert stage.counters()["commands"] == 2 and stage.counters()["refused"] == 1


def test_laser_off_by_command(box_world: World, head: SensorParameters) -> None:
    stage = HeadStage(box_world, seed=1)
    stage.start(0.0)
    off = _head_command(head, laser=False, seq=1)
    state = _only(stage.handle(topics.HEAD_COMMAND, off, 0.05), topics.HEAD_STATE)
    assert isinstance(state, HeadState)
    assert state.command_accepted and not state.laser_on and state.mode == "idle"
    assert "laser off" in state.command_message
    for _ in range(3):
        _, out = _tick_due(stage)
        assert [t for t, _ in out] == [topics.HEAD_STATE]
    on = _head_command(head, seq=2)
    state = _only(stage.handle(topics.HEAD_COMMAND, on, 0.4), topics.HEAD_STATE)
    assert isinstance(state, HeadState)
    assert state.laser_on and state.command_accepted
    _, out = _tick_due(stage)
    assert _only(out, topics.RAW_SCAN).time_s.size == 256
    assert stage.counters()["refused"] == 0


def test_watchdog_turns_the_laser_off(box_world: World, head: SensorParameters) -> None:
    stage = HeadStage(box_world, seed=1, watchdog_s=0.5)
    stage.start(0.0)
    scans = 0
    for _ in range(5):  # sweeps ending at 0.1 ... 0.5: within the watchdog
        _, out = _tick_due(stage)
        scans += len(_outputs(out, topics.RAW_SCAN))
    assert scans == 5 and stage.counters()["watchdog_trips"] == 0
    due, out = _tick_due(stage)
    assert due == pytest.approx(0.6)
    assert [t for t, _ in out] == [topics.HEAD_STATE]
    state = _only(out, topics.HEAD_STATE)
    assert isinstance(state, HeadState)
    assert not state.laser_on and state.mode == "fault"
    assert "no head command" in state.command_message
    for _ in range(5):  # stays off, counted once
        _, out = _tick_due(stage)
        assert [t for t, _ in out] == [topics.HEAD_STATE]
    assert stage.counters()["watchdog_trips"] == 1
    now = stage.next_tick_s()
    assert now is not None
    state = _only(stage.handle(topics.HEAD_COMMAND, _head_command(head), now), topics.HEAD_STATE)
    assert isinstance(state, HeadState)
    assert state.laser_on and state.mode == "scanning"
    _, out = _tick_due(stage)
    assert len(_outputs(out, topics.RAW_SCAN)) == 1


def test_commands_keep_the_watchdog_quiet(box_world: World, head: SensorParameters) -> None:
    stage = HeadStage(box_world, seed=1, watchdog_s=0.5)
    stage.start(0.0)
    last_command = 0.0
    for _ in range(15):
        due, out = _tick_due(stage)
        assert len(_outputs(out, topics.RAW_SCAN)) == 1
        if due - last_command >= 0.3:
            stage.handle(topics.HEAD_COMMAND, _head_command(head), due)
            last_command = due
    assert stage.counters()["watchdog_trips"] == 0


def test_a_command_while_panning_slews_within_the_rate_limit(
    box_world: World, head: SensorParameters
) -> None:
    stage = HeadStage(box_world, seed=1)
    stage.start(0.0)
    due, _ = _tick_due(stage)
    command = _head_command(head, pan_rad=0.5, seq=3)
    state = _only(stage.handle(topics.HEAD_COMMAND, command, due), topics.HEAD_STATE)
    assert isinstance(state, HeadState)
    assert state.mode == "slewing" and state.target_pan_rad == 0.5 and state.command_accepted
    _, out = _tick_due(stage)
    raw = _only(out, topics.RAW_SCAN)
    assert isinstance(raw, RawScan)
    assert np.all(np.diff(raw.pan_rad) > 0)  # the pan changes within the sweep
    rates = np.diff(raw.pan_rad) / np.diff(raw.time_s)
    assert np.max(rates) <= head.pan_rate_limit_rad_s * (1 + 1e-6)
    # From rest, at the acceleration limit, for one sweep.
    accel = head.pan_acceleration_limit_rad_s2
    assert raw.pan_rad[-1] == pytest.approx(0.5 * accel * head.sweep_period_s**2, rel=0.02)
    state = _only(out, topics.HEAD_STATE)
    assert isinstance(state, HeadState)
    assert state.mode == "slewing" and state.pan_rate_rad_s > 0
    modes = []
    for _ in range(10):
        _, out = _tick_due(stage)
        raw = _only(out, topics.RAW_SCAN)
        assert isinstance(raw, RawScan)
        rates = np.diff(raw.pan_rad) / np.diff(raw.time_s)
        assert np.max(np.abs(rates)) <= head.pan_rate_limit_rad_s * (1 + 1e-6)
        state = _only(out, topics.HEAD_STATE)
        assert isinstance(state, HeadState)
        modes.append(state.mode)
    assert modes[-1] == "scanning" and state.pan_rad == pytest.approx(0.5, abs=1e-4)
    assert state.pan_rate_rad_s == 0.0
    assert np.all(raw.pan_rad == 0.5)


def test_the_pan_starts_moving_when_the_command_arrives(
    box_world: World, head: SensorParameters
) -> None:
    stage = HeadStage(box_world, seed=1)
    stage.start(0.0)
    _tick_due(stage)
    stage.handle(topics.HEAD_COMMAND, _head_command(head, pan_rad=0.5), 0.15)
    _, out = _tick_due(stage)
    raw = _only(out, topics.RAW_SCAN)
    assert isinstance(raw, RawScan)
    before = raw.time_s < 0.15
    assert before.sum() > 100
    assert np.max(np.abs(raw.pan_rad[before])) < 1e-9


def _head_currents(world: World, seed: int, n: int = 3) -> list[FloatArray]:
    stage = HeadStage(world, seed=seed)
    stage.start(0.0)
    out = []
    for _ in range(n):
        _, outputs = _tick_due(stage)
        raw = _only(outputs, topics.RAW_SCAN)
        assert isinstance(raw, RawScan)
        out += [raw.current_1_A, raw.current_2_A]
    return out


def test_the_same_seed_gives_the_same_scans(box_world: World) -> None:
    a, b = _head_currents(box_world, 5), _head_currents(box_world, 5)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    c = _head_currents(box_world, 6)
    assert all(not np.array_equal(x, z) for x, z in zip(a, c, strict=True))


def test_head_counters(box_world: World, head: SensorParameters) -> None:
    stage = HeadStage(box_world, seed=1)
    stage.start(0.0)
    assert stage.counters() == {
        "commands": 0, "refused": 0, "late_sweeps": 0, "watchdog_trips": 0, "sweeps": 0,
    }  # fmt: skip
    _tick_due(stage)
    stage.handle(topics.HEAD_COMMAND, _head_command(head, pan_rad=0.2, seq=0), 0.11)
    stage.handle(topics.HEAD_COMMAND, _head_command(head, pan_rad=2.0, seq=1), 0.12)
    stage.handle(topics.HEAD_COMMAND, _head_command(head, window_deg=(-30, 0), seq=2), 0.13)
    stage.handle(topics.HEAD_COMMAND, _head_command(head, seq=3), 0.14)
    _tick_due(stage)
    # Other topics and other message types are not commands.
    stage.handle(topics.HEAD_STATE, _head_command(head), 0.25)
    stage.handle(topics.HEAD_COMMAND, WheelCommand(header=Header(), speed_m_s=0.0,
                                                   yaw_rate_rad_s=0.0), 0.26)  # fmt: skip
    due = stage.next_tick_s()
    assert due is not None
    out = stage.tick(due + 1.0)  # a stalled process: one late sweep, resynchronised
    assert len(_outputs(out, topics.RAW_SCAN)) == 1
    assert stage.next_tick_s() == pytest.approx(due + 1.0 + head.sweep_period_s)
    assert stage.counters() == {
        "commands": 4, "refused": 2, "late_sweeps": 1, "watchdog_trips": 0, "sweeps": 3,
    }  # fmt: skip


# ============================================================================================
# WorldStage
# ============================================================================================
START_POSE = (1.0, -0.5, 0.3)


def _world_stage(**kwargs: float) -> WorldStage:
    """The world stage with commands taking effect at once (no acceleration limit: these
    tests check the integration; the ramps are tests/unit/stages/test_world_motion.py's)."""
    world = World.build(walls=[(((3.0, -1.0), (3.0, 1.0)), 1.0)], vehicle_pose=START_POSE)
    kwargs.setdefault("max_accel_m_s2", math.inf)
    kwargs.setdefault("max_yaw_accel_rad_s2", math.inf)
    return WorldStage(world, **kwargs)


def _wheel(speed: float, yaw_rate: float) -> WheelCommand:
    return WheelCommand(header=Header(), speed_m_s=speed, yaw_rate_rad_s=yaw_rate)


def _run_world(stage: WorldStage, until_s: float) -> list[tuple[float, WorldTruth]]:
    truths = []
    while (due := stage.next_tick_s()) is not None and due <= until_s + 1e-9:
        msg = _only(stage.tick(due), topics.WORLD_TRUTH)
        assert isinstance(msg, WorldTruth)
        truths.append((due, msg))
    return truths


def _pose(truth: WorldTruth) -> tuple[float, float, float]:
    return truth.x_m, truth.y_m, truth.yaw_rad


def test_world_stands_still_without_a_command() -> None:
    stage = _world_stage(rate_hz=20.0)
    assert stage.start(0.0) == []
    truths = _run_world(stage, 1.0)
    assert len(truths) == 21
    for t, truth in truths:
        assert _pose(truth) == START_POSE
        assert truth.speed_m_s == 0.0 and truth.yaw_rate_rad_s == 0.0
        assert truth.header.stamp_ns == stamp_ns(t) and truth.header.frame_id == "world"


def _expected_pose(motion: ConstantTwist, t: float) -> tuple[float, float, float]:
    x, y, yaw = motion.poses_at(t)
    return float(x), float(y), math.remainder(float(yaw), math.tau)


def _assert_pose(truth: WorldTruth, expected: tuple[float, float, float]) -> None:
    x, y, yaw = expected
    assert truth.x_m == pytest.approx(x, abs=1e-9)
    assert truth.y_m == pytest.approx(y, abs=1e-9)
    assert math.remainder(truth.yaw_rad - yaw, math.tau) == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize(
    ("speed", "yaw_rate"), [(0.4, 0.0), (0.3, 0.8), (-0.2, -1.2), (0.0, 1.5)]
)  # fmt: skip
def test_world_integrates_a_wheel_command_exactly(speed: float, yaw_rate: float) -> None:
    stage = _world_stage(rate_hz=20.0, command_timeout_s=5.0)
    stage.start(0.0)
    stage.handle(topics.WHEEL_COMMAND, _wheel(speed, yaw_rate), 0.0)
    motion = ConstantTwist(*START_POSE, speed, yaw_rate, 0.0)
    truths = _run_world(stage, 2.0)
    assert len(truths) == 41
    for t, truth in truths:
        _assert_pose(truth, _expected_pose(motion, t))
        assert truth.speed_m_s == speed and truth.yaw_rate_rad_s == yaw_rate


def test_world_integrates_between_commands_at_any_time() -> None:
    stage = _world_stage(rate_hz=20.0, command_timeout_s=5.0)
    stage.start(0.0)
    stage.handle(topics.WHEEL_COMMAND, _wheel(0.3, 0.8), 0.013)
    _run_world(stage, 0.4)
    stage.handle(topics.WHEEL_COMMAND, _wheel(0.45, -0.5), 0.437)  # between ticks
    truths = _run_world(stage, 1.0)
    first = ConstantTwist(*START_POSE, 0.3, 0.8, 0.013)
    second = ConstantTwist(*_expected_pose(first, 0.437), 0.45, -0.5, 0.437)
    for t, truth in truths:
        _assert_pose(truth, _expected_pose(second, t))


def test_world_stops_when_the_command_times_out() -> None:
    stage = _world_stage(rate_hz=20.0, command_timeout_s=0.5)
    stage.start(0.0)
    stage.handle(topics.WHEEL_COMMAND, _wheel(0.4, 0.0), 0.0)
    truths = _run_world(stage, 1.5)
    motion = ConstantTwist(*START_POSE, 0.4, 0.0, 0.0)
    stopped = _expected_pose(motion, 0.5)
    for t, truth in truths:
        if t <= 0.5:
            _assert_pose(truth, _expected_pose(motion, t))
        else:
            _assert_pose(truth, stopped)
            assert truth.speed_m_s == 0.0 and truth.yaw_rate_rad_s == 0.0


@pytest.mark.parametrize(("command_s", "ticks"), [(0.02, None), (0.0, [0.0, 2.0])])
def test_world_moves_for_the_whole_timeout_whatever_the_tick_times(
    command_s: float, ticks: list[float] | None
) -> None:
    stage = _world_stage(rate_hz=20.0, command_timeout_s=0.5)
    stage.start(0.0)
    stage.handle(topics.WHEEL_COMMAND, _wheel(0.4, 0.0), command_s)
    if ticks is None:
        truth = _run_world(stage, 1.0)[-1][1]
    else:
        outputs = [out for t in ticks for out in stage.tick(t)]
        truth = outputs[-1][1]
    assert isinstance(truth, WorldTruth)
    motion = ConstantTwist(*START_POSE, 0.4, 0.0, command_s)
    _assert_pose(truth, _expected_pose(motion, command_s + 0.5))


def test_world_clamps_commands_to_the_platform_limits() -> None:
    stage = _world_stage(rate_hz=20.0, max_speed_m_s=0.5, max_yaw_rate_rad_s=1.5)
    stage.start(0.0)
    stage.handle(topics.WHEEL_COMMAND, _wheel(0.4, 1.0), 0.0)  # within the limits
    assert stage.counters() == {"wheel_commands": 1, "clamped": 0}
    stage.handle(topics.WHEEL_COMMAND, _wheel(1.5, 0.2), 0.01)
    assert (stage.speed, stage.yaw_rate) == (0.5, 0.2)
    stage.handle(topics.WHEEL_COMMAND, _wheel(-1.0, -3.0), 0.02)
    assert (stage.speed, stage.yaw_rate) == (-0.5, -1.5)
    stage.handle(topics.WHEEL_COMMAND, _wheel(0.1, 4.0), 0.03)
    truth = _only(stage.tick(0.03), topics.WORLD_TRUTH)
    assert isinstance(truth, WorldTruth)
    assert truth.speed_m_s == 0.1 and truth.yaw_rate_rad_s == 1.5
    assert stage.counters() == {"wheel_commands": 4, "clamped": 3}
    # Other topics and message types are not wheel commands.
    stage.handle(topics.HEAD_COMMAND, _wheel(0.2, 0.0), 0.04)
    assert stage.counters()["wheel_commands"] == 4


def test_world_truth_comes_at_its_rate_and_does_not_burst_after_a_stall() -> None:
    stage = _world_stage(rate_hz=20.0)
    stage.start(2.0)
    assert stage.next_tick_s() == 2.0
    times = [t for t, _ in _run_world(stage, 2.5)]
    assert len(times) == 11
    np.testing.assert_allclose(np.diff(times), 0.05, rtol=1e-9)
    # A little late: the phase is kept.
    due = stage.next_tick_s()
    assert due is not None
    stage.tick(due + 0.02)
    assert stage.next_tick_s() == pytest.approx(due + 0.05)
    # Stalled for seconds: one message now, the next one period later, no catching up.
    out = stage.tick(10.0)
    assert len(_outputs(out, topics.WORLD_TRUTH)) == 1
    assert stage.next_tick_s() == pytest.approx(10.05)
    times = [t for t, _ in _run_world(stage, 10.2)]
    np.testing.assert_allclose(times, [10.05, 10.1, 10.15, 10.2])


# ============================================================================================
# CalibrationStage
# ============================================================================================
def _plane_raw_scan(
    head: SensorParameters, seed: int, direction: int = 1
) -> tuple[RawScan, ScanTruth]:
    sim = SensorSimulator(plane_world(1.0), head, np.random.default_rng(seed))
    raw, truth = sim.sweep(
        direction=direction, trajectory=head_centred_pose(head), start_time_s=3.0
    )
    msg = RawScan(
        header=Header(stamp_ns=stamp_ns(float(raw.time_s[-1])), seq=4, frame_id="head",
                      source="head"),
        time_s=raw.time_s, mirror_angle_rad=raw.mirror_angle_rad, pan_rad=raw.pan_rad,
        current_1_A=raw.current_1_A, current_2_A=raw.current_2_A, direction=raw.direction,
        sweep_index=42,
    )  # fmt: skip
    return msg, truth


def test_calibration_stage_turns_a_raw_scan_into_a_calibrated_scan(
    head: SensorParameters, calibration: Calibration
) -> None:
    raw, truth = _plane_raw_scan(head, seed=3)
    stage = CalibrationStage(calibration)
    out = stage.handle(topics.RAW_SCAN, raw, 3.2)
    assert [t for t, _ in out] == [topics.CALIBRATED_SCAN]
    scan = out[0][1]
    assert isinstance(scan, CalibratedScan)
    assert scan.sweep_index == 42 and scan.header.stamp_ns == raw.header.stamp_ns
    assert scan.header.frame_id == "head" and scan.direction == raw.direction
    assert scan.range_m.size == raw.time_s.size
    np.testing.assert_array_equal(scan.pan_rad, raw.pan_rad)
    valid = np.isfinite(scan.range_m)
    assert valid.sum() >= 0.95 * valid.size
    z = (scan.range_m[valid] - truth.range_m[valid]) / scan.sigma_m[valid]
    assert np.max(np.abs(z)) < 5.0
    assert np.all(scan.sigma_m[valid] < 0.01)  # a plane at 1 m: millimetres
    assert stage.counters() == {"scans": 1}
    decode(scan.to_wire(), expect=CalibratedScan)  # a valid message on the wire


def test_calibration_stage_ignores_other_topics(
    head: SensorParameters, calibration: Calibration
) -> None:
    raw, _ = _plane_raw_scan(head, seed=3)
    stage = CalibrationStage(calibration)
    assert stage.handle(topics.HEAD_STATE, raw, 0.0) == []
    assert stage.handle(topics.RAW_SCAN, _wheel(0.0, 0.0), 0.0) == []
    assert stage.start(0.0) == [] and stage.tick(0.0) == [] and stage.next_tick_s() is None
    assert stage.counters() == {"scans": 0}


# ============================================================================================
# LockstepRunner
# ============================================================================================
Observed = list[tuple[float, str, Message]]


def _sim_rate_hz() -> float:
    text = SIM_LAUNCH.read_text(encoding="utf-8")
    rate = parse_launch(text, SIM_LAUNCH).process("world").params["rate_hz"]
    assert isinstance(rate, float)
    return rate


def _lockstep(calibration: Calibration, seed: int = 1) -> tuple[LockstepRunner, Observed]:
    world = load_world(BOX_WORLD)
    runner = LockstepRunner(
        [
            Node("world", WorldStage(world, rate_hz=20.0), (topics.WHEEL_COMMAND,)),
            Node("head", HeadStage(world, seed=seed), (topics.HEAD_COMMAND, topics.WORLD_TRUTH)),
            Node("calibration", CalibrationStage(calibration), (topics.RAW_SCAN,)),
        ]
    )
    seen: Observed = []
    runner.observe(lambda t, topic, msg: seen.append((t, topic, msg)))
    return runner, seen


def _count(seen: Observed, topic: str) -> int:
    return sum(1 for _, t, _ in seen if t == topic)


def test_lockstep_graph_runs_at_its_rates(calibration: Calibration) -> None:
    assert _sim_rate_hz() == 20.0
    runner, seen = _lockstep(calibration)
    runner.run_until(1.0)
    assert runner.now_s == 1.0
    assert _count(seen, topics.CALIBRATED_SCAN) == 10
    assert _count(seen, topics.RAW_SCAN) == 10
    assert 20 <= _count(seen, topics.WORLD_TRUTH) <= 21
    assert _count(seen, topics.HEAD_STATE) == 11  # at start, then with every sweep
    # Each calibrated scan goes out at the time of its raw scan.
    raw_times = [t for t, topic, _ in seen if topic == topics.RAW_SCAN]
    cal_times = [t for t, topic, _ in seen if topic == topics.CALIBRATED_SCAN]
    assert raw_times == cal_times
    np.testing.assert_allclose(raw_times, np.arange(1, 11) * 0.1, atol=1e-9)


def test_lockstep_runs_are_identical(calibration: Calibration) -> None:
    def record() -> list[tuple[float, str, bytes]]:
        runner, seen = _lockstep(calibration)
        runner.run_until(0.5)
        runner.inject(topics.WHEEL_COMMAND, _wheel(0.2, 0.3))
        runner.run_until(1.0)
        return [(t, topic, msg.to_wire()) for t, topic, msg in seen]

    first, second = record(), record()
    assert len(first) > 30
    assert first == second


def test_lockstep_inject_reaches_the_head_at_once(
    calibration: Calibration, head: SensorParameters
) -> None:
    runner, seen = _lockstep(calibration)
    runner.run_until(0.35)
    assert runner.now_s == 0.35
    before = len(seen)
    runner.inject(topics.HEAD_COMMAND, _head_command(head, pan_rad=0.3), source="controller")
    new = seen[before:]
    assert [topic for _, topic, _ in new] == [topics.HEAD_COMMAND, topics.HEAD_STATE]
    t_cmd, _, cmd = new[0]
    t_state, _, state = new[1]
    assert t_cmd == t_state == 0.35
    assert cmd.header.source == "controller" and cmd.header.stamp_ns == stamp_ns(0.35)
    assert isinstance(state, HeadState)
    assert state.header.source == "head" and state.header.stamp_ns == stamp_ns(0.35)
    assert state.target_pan_rad == 0.3 and state.command_seq == 0 and state.mode == "slewing"


def test_lockstep_messages_pass_through_the_wire(calibration: Calibration) -> None:
    runner, seen = _lockstep(calibration)
    runner.run_until(0.5)
    seqs: dict[tuple[str, str], list[int]] = {}
    for _, topic, msg in seen:
        seqs.setdefault((msg.header.source, topic), []).append(msg.header.seq)
    assert set(seqs) == {
        ("world", topics.WORLD_TRUTH),
        ("world", topics.ODOMETRY),
        ("head", topics.HEAD_STATE),
        ("head", topics.RAW_SCAN),
        ("calibration", topics.CALIBRATED_SCAN),
    }
    for numbers in seqs.values():
        assert numbers == list(range(len(numbers)))
    raw = next(msg for _, topic, msg in seen if topic == topics.RAW_SCAN)
    scan = next(msg for _, topic, msg in seen if topic == topics.CALIBRATED_SCAN)
    assert isinstance(raw, RawScan) and isinstance(scan, CalibratedScan)
    for array in (raw.time_s, raw.current_1_A, scan.range_m, scan.sigma_m):
        assert not array.flags.writeable
        with pytest.raises(ValueError, match="read-only"):
            array[0] = 0.0


# ============================================================================================
# ProcessShell with a fake bus
# ============================================================================================
SHELL_LAUNCH = """
[graph]
name = "shell-test"
heartbeat_s = 0.5
join_timeout_s = 0.01

[[process]]
name = "calibration"
module = "processes.calibration"
inputs = ["raw_scan"]
outputs = ["calibrated_scan"]

[[external]]
name = "head"
endpoint = "ipc://{runtime}/head.pub"
outputs = ["raw_scan"]
"""


class FakeClock:
    def __init__(self, start_s: float = 100.0) -> None:
        self.now_s = start_s

    def __call__(self) -> float:
        return self.now_s


class FakeBus:
    """Bus's interface without sockets: scripted input batches, published messages recorded.

    Each ``poll`` advances the fake clock by its timeout and returns the next scripted batch
    (empty batches after the script ends, up to a limit: a shell that never stops fails).
    """

    def __init__(self, clock: FakeClock, script: list[list[tuple[str, bytes]]]) -> None:
        self.clock = clock
        self.script = deque(script)
        self.subscriber = self
        self.publisher = self
        self.connected: list[str] = []
        self.subscribed: list[str] = []
        self.published: list[tuple[str, Message]] = []
        self.idle_polls = 0
        self.closed = False
        self.links_dropped = 0

    def connect(self, endpoint: str) -> None:
        self.connected.append(endpoint)

    def subscribe(self, topic: str) -> None:
        self.subscribed.append(topic)

    def subscriber_count(self, topic: str) -> int:
        return 0

    def poll_subscriptions(self, timeout_s: float) -> None:
        self.clock.now_s += timeout_s  # waiting for subscribers reads no input

    def poll(self, timeout_s: float) -> list[tuple[str, bytes]]:
        assert 0.0 <= timeout_s <= MAX_POLL_S
        self.clock.now_s += timeout_s
        if self.script:
            return self.script.popleft()
        self.idle_polls += 1
        if self.idle_polls > 100:
            raise RuntimeError("the shell did not stop at the end of the script")
        return []

    def publish(self, topic: str, payload: bytes) -> None:
        self.published.append((topic, decode(payload, expect=topics.message_type(topic))))

    def close(self) -> None:
        self.closed = True

    def on(self, topic: str) -> list[Message]:
        return [msg for t, msg in self.published if t == topic]

    def heartbeats(self) -> list[Heartbeat]:
        beats = [m for m in self.on(topics.HEARTBEAT) if isinstance(m, Heartbeat)]
        assert len(beats) == len(self.on(topics.HEARTBEAT))
        return beats


@pytest.fixture(scope="module")
def raw_template(head: SensorParameters) -> RawScan:
    return _plane_raw_scan(head, seed=9)[0]


def _raw_payload(template: RawScan, seq: int, source: str = "head") -> bytes:
    return template.with_header(seq=seq, source=source).to_wire()


def _stop(process: str = "") -> tuple[str, bytes]:
    return topics.STOP, Stop(header=Header(source="launcher"), process=process).to_wire()


def _shell(
    calibration: Calibration,
    script: list[list[tuple[str, bytes]]],
    stage: CalibrationStage | None = None,
    launch: str = SHELL_LAUNCH,
) -> tuple[ProcessShell, FakeBus]:
    graph = parse_launch(launch).resolve("/run/test-graph")
    clock = FakeClock()
    bus = FakeBus(clock, script)
    stage = CalibrationStage(calibration) if stage is None else stage
    shell = ProcessShell(graph, graph.process("calibration"), stage, clock=clock, bus=bus)
    return shell, bus


def test_shell_connects_to_its_inputs_and_the_control_endpoint(
    calibration: Calibration,
) -> None:
    _, bus = _shell(calibration, [])
    assert bus.connected == ["ipc:///run/test-graph/head.pub", "ipc:///run/test-graph/launcher.pub"]
    assert bus.subscribed == [topics.RAW_SCAN, topics.STOP]


def test_shell_calibrates_raw_scans_and_stops_on_request(
    calibration: Calibration, raw_template: RawScan
) -> None:
    script = [
        [(topics.RAW_SCAN, _raw_payload(raw_template, 0))],
        [],
        [(topics.RAW_SCAN, _raw_payload(raw_template, 1))],
        [(topics.RAW_SCAN, _raw_payload(raw_template, 2)), _stop("calibration")],
    ]
    shell, bus = _shell(calibration, script)
    assert shell.run() == 0
    assert bus.idle_polls == 0
    scans = bus.on(topics.CALIBRATED_SCAN)
    assert len(scans) == 3
    for i, scan in enumerate(scans):
        assert isinstance(scan, CalibratedScan)
        assert scan.header.source == "calibration" and scan.header.seq == i
        assert scan.header.stamp_ns == raw_template.header.stamp_ns
        assert scan.sweep_index == raw_template.sweep_index
    beats = bus.heartbeats()
    assert beats[0].state == "starting" and beats[-1].state == "stopping"
    assert {b.state for b in beats[1:-1]} == {"running"}
    assert bus.published[-1][1] is beats[-1]  # the last word is the final heartbeat
    assert [b.header.seq for b in beats] == list(range(len(beats)))
    assert all(b.process == "calibration" and b.header.source == "calibration" for b in beats)
    final = beats[-1].counters
    assert final["received"] == 3 and final["scans"] == 3 and final["lost"] == 0
    assert final["published"] == len(bus.published) - 1  # all but the final heartbeat
    assert not any(k.startswith("dropped_") for k in final)


def test_shell_stops_on_a_stop_for_every_process(
    calibration: Calibration, raw_template: RawScan
) -> None:
    shell, bus = _shell(calibration, [[], [_stop("")]])
    assert shell.run() == 0
    assert bus.idle_polls == 0
    assert bus.heartbeats()[-1].state == "stopping"
    assert bus.on(topics.CALIBRATED_SCAN) == []


def test_shell_ignores_a_stop_for_another_process(
    calibration: Calibration, raw_template: RawScan
) -> None:
    script = [
        [_stop("head")],
        [_stop("calibration-2")],
        [(topics.RAW_SCAN, _raw_payload(raw_template, 0))],
        [_stop("calibration")],
    ]
    shell, bus = _shell(calibration, script)
    assert shell.run() == 0
    assert len(bus.on(topics.CALIBRATED_SCAN)) == 1  # still working after the other stops
    assert bus.idle_polls == 0


def _malformed_payloads(template: RawScan) -> dict[str, list[tuple[str, bytes]]]:
    good = _raw_payload(template, 0)
    hot = RawScan(
        header=template.header, time_s=template.time_s,
        mirror_angle_rad=template.mirror_angle_rad, pan_rad=template.pan_rad,
        current_1_A=np.full_like(template.current_1_A, 2e-3), current_2_A=template.current_2_A,
        direction=template.direction, sweep_index=0,
    )  # fmt: skip
    header = {"stamp_ns": 0, "seq": 0, "frame_id": "", "source": "head"}
    state = HeadState(header=Header(), pan_rad=0.0, pan_rate_rad_s=0.0, target_pan_rad=0.0,
                      window_low_rad=-0.1, window_high_rad=0.1, laser_on=True,
                      mode="scanning", command_seq=-1, sweeps=0)  # fmt: skip
    return {
        "truncated": [
            (topics.RAW_SCAN, good[: len(good) // 2]),
            (topics.RAW_SCAN, b""),
        ],
        "malformed": [
            (topics.RAW_SCAN, msgpack.packb([1, 2, 3])),
            (topics.RAW_SCAN, b"\xc1"),
            (topics.RAW_SCAN, good + b"\x00"),
        ],
        "unknown_type": [
            (topics.RAW_SCAN, state.to_wire()),
            (topics.HEAD_STATE, state.to_wire()),  # not an input of this process
        ],
        "wrong_version": [
            (topics.RAW_SCAN, msgpack.packb({"type": "raw_scan/2", "header": header})),
        ],
        "oversized": [
            (topics.RAW_SCAN, msgpack.packb({"type": "raw_scan/" + "1" * 300})),
        ],
        "out_of_range": [(topics.RAW_SCAN, hot.to_wire())],
    }


def test_shell_counts_and_logs_malformed_input_and_keeps_working(
    calibration: Calibration, raw_template: RawScan, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="process.calibration")
    bad = _malformed_payloads(raw_template)
    script = [[item] for items in bad.values() for item in items]
    script.append([(topics.RAW_SCAN, _raw_payload(raw_template, 1))])
    script.append([_stop()])
    shell, bus = _shell(calibration, script)
    assert shell.run() == 0
    assert len(bus.on(topics.CALIBRATED_SCAN)) == 1
    final = bus.heartbeats()[-1].counters
    for kind, items in bad.items():
        assert final[f"dropped_{kind}"] == len(items), kind
    assert final["received"] == sum(len(items) for items in bad.values()) + 1
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == len(bad)  # once per kind
    for record in warnings:
        assert "\n" not in record.getMessage()
    for kind in bad:
        assert sum(f"[{kind}]" in r.getMessage() for r in warnings) == 1, kind


def test_shell_counts_malformed_stop_messages(calibration: Calibration) -> None:
    script = [[(topics.STOP, b"\x01")], [_stop()]]
    shell, bus = _shell(calibration, script)
    assert shell.run() == 0
    assert bus.heartbeats()[-1].counters["dropped_malformed"] == 1


def test_shell_counts_sequence_gaps_as_lost(
    calibration: Calibration, raw_template: RawScan
) -> None:
    seqs = [("head", 0), ("head", 1), ("head", 4), ("other", 7), ("head", 5), ("head", 9)]
    seqs += [("head", 0), ("head", 1)]  # a publisher restart: not a loss
    script = [[(topics.RAW_SCAN, _raw_payload(raw_template, s, src))] for src, s in seqs]
    script.append([_stop()])
    shell, bus = _shell(calibration, script)
    assert shell.run() == 0
    assert len(bus.on(topics.CALIBRATED_SCAN)) == len(seqs)
    assert bus.heartbeats()[-1].counters["lost"] == 2 + 3


def test_shell_heartbeats_at_its_period_on_the_clock(
    calibration: Calibration,
) -> None:
    shell, bus = _shell(calibration, [[] for _ in range(20)] + [[_stop()]])
    start = shell.clock()
    assert shell.run() == 0
    beats = bus.heartbeats()
    running = [b for b in beats if b.state == "running"]
    elapsed = shell.clock() - start  # 21 polls, each as long as the shell asks
    assert elapsed <= 21 * MAX_POLL_S + 1e-9
    assert len(running) >= 5  # polls wait: the clock moved on, heartbeats came
    assert len(running) == pytest.approx(elapsed / 0.5, abs=1.5)
    stamps = np.array([b.header.stamp_ns for b in running]) * 1e-9
    np.testing.assert_allclose(np.diff(stamps), 0.5, atol=1e-6)


class TimedFakeBus(FakeBus):
    """A FakeBus whose input batches arrive at scripted times on the fake clock: a poll
    returns the next batch if it is due within its timeout (the clock moves to it)."""

    def __init__(self, clock: FakeClock, timed: list[tuple[float, list[tuple[str, bytes]]]]):
        super().__init__(clock, [])
        self.timed = deque(timed)

    def poll(self, timeout_s: float) -> list[tuple[str, bytes]]:
        assert 0.0 <= timeout_s <= MAX_POLL_S
        if self.timed and self.timed[0][0] <= self.clock.now_s + timeout_s:
            due, batch = self.timed.popleft()
            self.clock.now_s = max(self.clock.now_s, due)
            return batch
        return super().poll(timeout_s)


def test_shell_heartbeats_say_what_was_published_per_topic(
    calibration: Calibration, raw_template: RawScan
) -> None:
    """The launcher's count and settled rate of a topic, from the publisher's heartbeats alone:
    20 scans queued at start-up arrive in a burst, then 40 at 10 Hz."""
    start = 100.0
    arrivals = [start + 1.0 + 0.001 * k for k in range(20)]
    arrivals += [arrivals[-1] + 0.1 * k for k in range(1, 41)]
    timed = [
        (t, [(topics.RAW_SCAN, _raw_payload(raw_template, k))]) for k, t in enumerate(arrivals)
    ]
    timed.append((arrivals[-1] + 0.05, [_stop()]))
    graph = parse_launch(SHELL_LAUNCH).resolve("/run/test-graph")
    clock = FakeClock(start)
    bus = TimedFakeBus(clock, timed)
    shell = ProcessShell(
        graph, graph.process("calibration"), CalibrationStage(calibration), clock=clock, bus=bus
    )
    assert shell.run() == 0
    beats = bus.heartbeats()
    final = beats[-1].counters
    assert final["published_calibrated_scan"] == 60
    assert final["last_published_ns_calibrated_scan"] == round(arrivals[-1] * 1e9)
    assert final["published_heartbeat"] == len(beats) - 1  # the last beat not yet counted
    published = PublishedStats()
    for beat in beats:
        if "published_calibrated_scan" in beat.counters:
            published.see(
                beat.process,
                beat.pid,
                beat.counters["published_calibrated_scan"],
                beat.counters["last_published_ns_calibrated_scan"],
            )
    heard = TopicStats()
    for t in arrivals:  # what a listener hearing every message would have measured
        heard.see(t)
    assert published.count == heard.count == 60
    assert heard.rate_hz() == pytest.approx(10.0)
    # The window starts at the first heartbeat inside the later half: the same settled rate.
    assert published.rate_hz() == pytest.approx(10.0)


def test_published_stats_carry_a_restarted_publisher_s_count_over() -> None:
    stats = PublishedStats()
    for pid, count, last_s in [(7, 10, 1.0), (7, 20, 2.0), (7, 20, 2.0), (8, 5, 4.5), (8, 15, 5.5)]:
        stats.see("calibration", pid, count, round(last_s * 1e9))
    assert stats.count == 35  # 20 in its first life, 15 in its second
    assert [n for n, _ in stats.samples] == [10, 20, 25, 35]  # no news: no sample
    # The later half (messages 18 to 35) starts at the sample of message 20, before the
    # restart: its silence counts, as a listener's would.
    assert stats.rate_hz() == pytest.approx((35 - 20) / (5.5 - 2.0))
    assert PublishedStats().rate_hz() == 0.0


def test_shell_handles_only_the_newest_of_a_stale_backlog(
    calibration: Calibration, raw_template: RawScan
) -> None:
    """Five scans queued at once (the process stalled): the newest is calibrated, the older
    four are dropped unread and counted; what follows flows as usual."""
    backlog = [(topics.RAW_SCAN, _raw_payload(raw_template, seq)) for seq in range(5)]
    later = [(topics.RAW_SCAN, _raw_payload(raw_template, 5))]
    script = [backlog, [], later, [_stop()]]  # the empty read ends the drain
    shell, bus = _shell(calibration, script)
    assert shell.run() == 0
    scans = bus.on(topics.CALIBRATED_SCAN)
    assert len(scans) == 2
    final = bus.heartbeats()[-1].counters
    assert final["stale_dropped"] == 4 and final["received"] == 2
    assert final["lost"] == 0  # dropped here on purpose, not lost on the way


def test_shell_reads_the_backlog_still_on_its_way_before_choosing(
    calibration: Calibration, raw_template: RawScan
) -> None:
    """The backlog arrives in two reads: the second is drained before choosing, so only the
    newest of all six is handled."""
    first = [(topics.RAW_SCAN, _raw_payload(raw_template, seq)) for seq in range(3)]
    second = [(topics.RAW_SCAN, _raw_payload(raw_template, seq)) for seq in range(3, 6)]
    shell, bus = _shell(calibration, [first, second, [_stop()]])
    assert shell.run() == 0
    assert len(bus.on(topics.CALIBRATED_SCAN)) == 1
    assert bus.heartbeats()[-1].counters["stale_dropped"] == 5


class StallingFakeBus(FakeBus):
    """A FakeBus whose first poll returns 1.2 s late (the process was stopped meanwhile)."""

    def poll(self, timeout_s: float) -> list[tuple[str, bytes]]:
        if not hasattr(self, "stalled"):
            self.stalled = True
            self.clock.now_s += 1.2
        return super().poll(timeout_s)


def test_shell_after_a_stall_drains_a_backlog_that_trickles_in(
    calibration: Calibration, raw_template: RawScan
) -> None:
    """After a stall the backlog arrives one message per read: it is read until none comes,
    and only the newest of the three is handled (each would be, as it came, otherwise)."""
    one = [[(topics.RAW_SCAN, _raw_payload(raw_template, seq))] for seq in range(3)]
    shell, bus = _shell(calibration, [*one, [], [_stop()]])
    shell.bus = bus = StallingFakeBus(bus.clock, bus.script)
    assert shell.run() == 0
    assert len(bus.on(topics.CALIBRATED_SCAN)) == 1
    assert bus.heartbeats()[-1].counters["stale_dropped"] == 2


def _stamped_scan(template: RawScan, seq: int, stamp_s: float) -> tuple[str, bytes]:
    msg = template.with_header(seq=seq, source="head", stamp_ns=round(stamp_s * 1e9))
    return topics.RAW_SCAN, msg.to_wire()


def _run_paced(
    calibration: Calibration, paced: list[tuple[float, list[tuple[str, bytes]]]]
) -> tuple[list[float], dict[str, int]]:
    """Run the calibration shell on a PacedFakeBus from 100 s: the stamps (s, 2 decimals)
    of the scans it calibrated, and its final counters."""
    graph = parse_launch(SHELL_LAUNCH).resolve("/run/test-graph")
    clock = FakeClock(100.0)
    bus = PacedFakeBus(clock, paced)
    shell = ProcessShell(
        graph, graph.process("calibration"), CalibrationStage(calibration), clock=clock, bus=bus
    )
    assert shell.run() == 0
    handled = [round(m.header.stamp_ns * 1e-9, 2) for m in bus.on(topics.CALIBRATED_SCAN)]
    return handled, bus.heartbeats()[-1].counters


class PacedFakeBus(FakeBus):
    """A FakeBus whose script says how far the clock moves before each read returns."""

    def __init__(self, clock: FakeClock, paced: list[tuple[float, list[tuple[str, bytes]]]]):
        super().__init__(clock, [])
        self.paced = deque(paced)

    def poll(self, timeout_s: float) -> list[tuple[str, bytes]]:
        if not self.paced:
            return super().poll(timeout_s)
        advance_s, batch = self.paced.popleft()
        self.clock.now_s += advance_s
        return batch


def test_shell_after_a_stall_drops_backlog_that_trickles_in_after_the_drain(
    calibration: Calibration, raw_template: RawScan
) -> None:
    """Scans at 10 Hz, each read 20 ms after its stamp; the process stalls 1.6 s; three old
    scans are queued when it resumes, the drain ends, then one more old scan trickles in, then
    fresh ones. Every scan lagging more than STALL_S beyond the usual 20 ms is dropped, the
    newest of the drained backlog too; the fresh ones flow."""
    scan = functools.partial(_stamped_scan, raw_template)
    paced = [(0.1, [scan(k, 100.08 + 0.1 * k)]) for k in range(5)]  # read at 100.1 .. 100.5
    paced += [
        (1.6, [scan(5, 100.58), scan(6, 100.68), scan(7, 100.78)]),  # read at 102.1
        (0.0, []),  # the drain after a stall ends
        (0.0, []),  # and the drain of any backlog
        (0.05, [scan(8, 100.88)]),  # trickles in at 102.15, 1.27 s late
        (0.05, [scan(9, 102.18)]),  # fresh
        (0.1, [scan(10, 102.28)]),
        (0.01, [_stop()]),
    ]
    handled, final = _run_paced(calibration, paced)
    assert handled == [100.08, 100.18, 100.28, 100.38, 100.48, 102.18, 102.28]
    assert final["stale_dropped"] == 4 and final["lost"] == 0


def test_shell_believes_a_pipeline_that_got_slower_for_good(
    calibration: Calibration, raw_template: RawScan
) -> None:
    """After a stall every scan lags 0.5 s (upstream got slower, not a backlog): they are
    dropped for CATCH_UP_S at most, then handled again."""
    scan = functools.partial(_stamped_scan, raw_template)
    paced = [(0.1, [scan(k, 100.08 + 0.1 * k)]) for k in range(5)]  # read at 100.1 .. 100.5
    paced.append((1.6, []))  # stalled until 102.1
    paced += [(0.1, [scan(5 + k, 101.7 + 0.1 * k)]) for k in range(40)]  # 0.5 s late each
    paced.append((0.01, [_stop()]))
    handled, _ = _run_paced(calibration, paced)
    dropped = 5 + 40 - len(handled)
    assert handled[:5] == [100.08, 100.18, 100.28, 100.38, 100.48]
    assert handled[5:] == [round(101.7 + 0.1 * k, 2) for k in range(dropped, 40)]
    assert CATCH_UP_S * 10 - 1 <= dropped <= CATCH_UP_S * 10 + 1


def test_shell_with_backlog_all_handles_every_queued_message(
    calibration: Calibration, raw_template: RawScan
) -> None:
    backlog = [(topics.RAW_SCAN, _raw_payload(raw_template, seq)) for seq in range(5)]
    launch = SHELL_LAUNCH.replace(
        'outputs = ["calibrated_scan"]', 'outputs = ["calibrated_scan"]\nbacklog = "all"'
    )
    shell, bus = _shell(calibration, [backlog, [_stop()]], launch=launch)
    assert shell.run() == 0
    assert len(bus.on(topics.CALIBRATED_SCAN)) == 5
    assert bus.heartbeats()[-1].counters["stale_dropped"] == 0


def test_shell_drops_a_payload_over_its_topics_limit_unread(
    calibration: Calibration, raw_template: RawScan
) -> None:
    huge = b"\x00" * (topics.MAX_BYTES[topics.RAW_SCAN] + 1)
    script = [[(topics.RAW_SCAN, huge)], [(topics.RAW_SCAN, _raw_payload(raw_template, 0))]]
    shell, bus = _shell(calibration, [*script, [_stop()]])
    assert shell.run() == 0
    assert len(bus.on(topics.CALIBRATED_SCAN)) == 1
    final = bus.heartbeats()[-1].counters
    assert final["dropped_oversized"] == 1 and "dropped_malformed" not in final


class FlakyStage(CalibrationStage):
    """Fails on the scans whose sequence number is listed."""

    def __init__(self, calibration: Calibration, failing: set[int]) -> None:
        super().__init__(calibration)
        self.failing = failing

    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        if msg.header.seq in self.failing:
            raise ZeroDivisionError(f"scan {msg.header.seq} divides by zero")
        return super().handle(topic, msg, now_s)


def test_a_stage_error_drops_its_input_is_counted_and_logged_once(
    calibration: Calibration, raw_template: RawScan, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="process.calibration")
    script = [[(topics.RAW_SCAN, _raw_payload(raw_template, seq))] for seq in range(6)]
    stage = FlakyStage(calibration, failing={1, 3, 4})
    shell, bus = _shell(calibration, [*script, [_stop()]], stage=stage)
    assert shell.run() == 0
    assert len(bus.on(topics.CALIBRATED_SCAN)) == 3  # scans 0, 2 and 5
    beats = bus.heartbeats()
    final = beats[-1].counters
    assert final["stage_errors_ZeroDivisionError"] == 3 and final["stage_errors"] == 3
    assert "fault" not in {b.state for b in beats}  # never FAULT_AFTER in a row
    errors = [r for r in caplog.records if r.levelno == logging.ERROR]
    assert len(errors) == 1  # once per kind within ERROR_LOG_S
    assert "scan 1 divides by zero" in errors[0].getMessage()
    assert "\n" not in errors[0].getMessage()


def test_a_stage_failing_on_every_input_beats_fault_and_recovers(
    calibration: Calibration, raw_template: RawScan
) -> None:
    failing = set(range(FAULT_AFTER + 2))
    count = len(failing) + 1
    script = [[(topics.RAW_SCAN, _raw_payload(raw_template, seq))] for seq in range(count)]
    shell, bus = _shell(calibration, [*script, [], [], [_stop()]], FlakyStage(calibration, failing))
    assert shell.run() == 0  # it keeps running: no exit, so no restart storm
    states = [b.state for b in bus.heartbeats()]
    assert "fault" in states
    first_fault = states.index("fault")
    assert bus.heartbeats()[first_fault].counters["stage_errors"] == FAULT_AFTER
    assert states[-2] == "running"  # the last scan succeeded: the fault is cleared
    assert len(bus.on(topics.CALIBRATED_SCAN)) == 1
