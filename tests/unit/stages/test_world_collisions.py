"""The world stage's collisions: the vehicle's outline against walls, cylinders and movers."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from agent.runtime import topics
from agent.runtime.messages import Header, WheelCommand, WorldTruth, decode
from agent.sim.footprint import outline_clearance
from agent.sim.movers import Mover
from agent.sim.world import World
from agent.sim.world_file import load_world
from agent.stages.world_stage import MAX_REPORTED_CLEARANCE_M, WorldStage

REPO = Path(__file__).resolve().parents[3]
THIN_WALL = (((2.0, -3.0), (2.0, 3.0)), 1.0)  # a wall of no thickness across the way at x = 2


def _wheel(speed: float, yaw_rate: float) -> WheelCommand:
    return WheelCommand(header=Header(), speed_m_s=speed, yaw_rate_rad_s=yaw_rate)


def _truth(stage: WorldStage, now_s: float) -> WorldTruth:
    out = stage.tick(now_s)
    truth = out[-1][1]
    assert isinstance(truth, WorldTruth)
    return truth


def _still(position: tuple[float, float], radius: float = 0.2) -> Mover:
    """A mover standing still (speed 0 on a path of one repeated point)."""
    return Mover(radius, 1.0, np.array([position, position]), 0.0)


@pytest.mark.parametrize("rate_hz", [50.0, 2.0, 0.01])
def test_the_vehicle_stops_at_a_thin_wall_however_seldom_it_is_ticked(rate_hz: float) -> None:
    """Driving at 0.5 m/s, the front (0.4 m ahead of the centre) meets the wall at x = 2 when
    the centre reaches x = 1.6. At 0.01 Hz a tick comes after 100 s, when the vehicle would
    be 49 m on: tested only at ticks, it would pass through the wall."""
    world = World.build(walls=[THIN_WALL])
    stage = WorldStage(world, rate_hz=rate_hz, command_timeout_s=1000.0)
    stage.start(0.0)
    stage.handle(topics.WHEEL_COMMAND, _wheel(0.5, 0.0), 0.0)
    t = 0.0
    while t < 10.0:
        t = stage.next_tick_s() or 0.0
        truth = _truth(stage, t)
    assert stage.collision == "vehicle" and stage.collision_obstacle == 0
    assert stage.x == pytest.approx(1.6, abs=1e-5)  # in contact, not through
    assert (stage.y, stage.yaw) == (0.0, 0.0)
    # 1 s to reach 0.5 m/s (0.25 m), then 1.35 m at 0.5 m/s: contact at 3.7 s.
    assert stage.collision_time_s == pytest.approx(3.7, abs=1e-3)
    assert stage.speed == 0.0 and stage.yaw_rate == 0.0
    assert stage.min_clearance_m == 0.0 and stage.clearance_m == 0.0
    assert truth.collision == "vehicle" and truth.collision_obstacle == 0
    assert truth.clearance_m == 0.0 and truth.min_clearance_m == 0.0
    back = decode(truth.to_wire())
    assert isinstance(back, WorldTruth) and back.collision == "vehicle"


def test_contact_while_speeding_up_and_turning() -> None:
    """Wall at x = 0.5, the front at 0.4: contact after 0.1 m of a ramp at 0.5 m/s², at
    t = sqrt(2 * 0.1 / 0.5) = 0.632 s, if the vehicle drives straight; turning as well, the
    front-left corner leads, and the contact pose is the footprint's first contact."""
    world = World.build(walls=[(((0.5, -3.0), (0.5, 3.0)), 1.0)])
    stage = WorldStage(world, rate_hz=20.0, command_timeout_s=100.0)
    stage.start(0.0)
    stage.handle(topics.WHEEL_COMMAND, _wheel(0.5, 0.0), 0.0)
    _truth(stage, 2.0)
    assert stage.collision_time_s == pytest.approx(math.sqrt(0.4), abs=1e-5)
    assert stage.x == pytest.approx(0.1, abs=1e-5)
    stage = WorldStage(world, rate_hz=20.0, command_timeout_s=100.0)
    stage.start(0.0)
    stage.handle(topics.WHEEL_COMMAND, _wheel(0.5, -1.0), 0.0)
    _truth(stage, 2.0)
    assert stage.collision == "vehicle" and stage.collision_time_s < math.sqrt(0.4)
    pose = (stage.x, stage.y, stage.yaw)
    assert outline_clearance(world, pose)[0] == 0.0
    # A little earlier on the same path it was clear: at most 5 µm of motion between.
    back = (stage.x - 5e-6, stage.y, stage.yaw)
    assert 0.0 < outline_clearance(world, back)[0] <= 1e-5 + 5e-6


def test_after_a_collision_commands_are_ignored_and_counted() -> None:
    world = World.build(walls=[THIN_WALL])
    stage = WorldStage(world, rate_hz=20.0, command_timeout_s=100.0)
    stage.start(0.0)
    stage.handle(topics.WHEEL_COMMAND, _wheel(0.5, 0.0), 0.0)
    _truth(stage, 5.0)
    assert stage.collision == "vehicle"
    pose = (stage.x, stage.y, stage.yaw)
    assert stage.counters() == {"wheel_commands": 1, "clamped": 0}
    for i in range(3):  # backing away would be the thing to do; too late
        stage.handle(topics.WHEEL_COMMAND, _wheel(-0.5, 1.0), 5.0 + i)
    truth = _truth(stage, 20.0)
    assert (stage.x, stage.y, stage.yaw) == pose
    assert truth.speed_m_s == 0.0 and truth.yaw_rate_rad_s == 0.0
    assert stage.counters() == {"wheel_commands": 4, "clamped": 0, "commands_ignored": 3}
    assert stage.collision_time_s == pytest.approx(3.7, abs=1e-3)  # the first contact's


def test_a_mover_that_walks_into_a_standing_vehicle_is_the_movers_collision() -> None:
    # A mover of radius 0.2 walks down x = 0 from y = 3 at 0.5 m/s; the vehicle's left side is
    # at y = 0.3: contact when its centre reaches y = 0.5, at 5 s.
    mover = Mover(0.2, 1.0, np.array([[0.0, 3.0], [0.0, -3.0]]), 0.5)
    world = World.build(walls=[THIN_WALL], movers=[mover])
    stage = WorldStage(world, rate_hz=20.0)
    stage.start(0.0)
    truth = _truth(stage, 4.0)
    assert truth.collision == "" and truth.collision_obstacle == -1
    assert truth.clearance_m == pytest.approx(0.5, abs=1e-9)  # centre at y = 1: 1 - 0.3 - 0.2
    truth = _truth(stage, 6.0)
    assert stage.collision == "mover"
    assert stage.collision_obstacle == world.mover_id_base == 1
    assert stage.collision_time_s == pytest.approx(5.0, abs=1e-4)
    assert truth.collision == "mover" and truth.collision_obstacle == 1
    # The mover walks on through (blindly); the clearance now is 0 then grows again, the
    # least so far stays 0.
    truth = _truth(stage, 8.0)  # centre at y = -1: 0.7 - 0.2 off the right side
    assert truth.clearance_m == pytest.approx(0.5, abs=1e-9)
    assert truth.min_clearance_m == 0.0 and truth.collision == "mover"


@pytest.mark.parametrize(
    ("speed", "yaw_rate", "who"),
    [
        (0.3, 0.0, "vehicle"),  # drives into it
        (0.04, 0.0, "mover"),  # creeps, slower than moving_speed_m_s (0.05): "stopped"
        (0.0, 0.5, "vehicle"),  # turns on the spot: its corners sweep at 0.25 m/s
    ],
)
def test_who_moved_into_whom(speed: float, yaw_rate: float, who: str) -> None:
    # A mover standing 0.1 m off the front-left corner's path.
    target = (0.85, 0.35) if yaw_rate == 0.0 else (0.0, 0.55)
    world = World.build(movers=[_still(target, 0.1)])
    stage = WorldStage(world, rate_hz=20.0, command_timeout_s=100.0)
    stage.start(0.0)
    stage.handle(topics.WHEEL_COMMAND, _wheel(speed, yaw_rate), 0.0)
    _truth(stage, 30.0)
    assert stage.collision == who
    assert stage.collision_obstacle == 0  # the only mover, and no static obstacle


def test_creeping_into_a_wall_is_still_the_vehicles_collision() -> None:
    world = World.build(walls=[(((0.45, -1.0), (0.45, 1.0)), 1.0)])
    stage = WorldStage(world, rate_hz=20.0, command_timeout_s=100.0)
    stage.start(0.0)
    stage.handle(topics.WHEEL_COMMAND, _wheel(0.01, 0.0), 0.0)
    _truth(stage, 10.0)
    assert stage.collision == "vehicle" and stage.collision_obstacle == 0
    assert stage.x == pytest.approx(0.05, abs=1e-5)


def test_a_fast_small_mover_cannot_slip_through_between_ticks() -> None:
    # A 3 m/s mover of radius 5 mm crosses the vehicle's 0.8 m length in 0.27 s: a 1 Hz
    # world that tested only at ticks would see it 3 m apart each time.
    mover = Mover(0.005, 1.0, np.array([[-6.0, 0.0], [6.0, 0.0]]), 3.0)
    world = World.build(movers=[mover])
    stage = WorldStage(world, rate_hz=1.0)
    stage.start(0.0)
    for t in range(1, 4):
        _truth(stage, float(t))
    assert stage.collision == "mover"
    # It reaches the rear (x = -0.4 - 0.005) after 5.595 m: 1.865 s.
    assert stage.collision_time_s == pytest.approx(5.595 / 3.0, abs=1e-4)


def test_a_start_pose_in_contact_is_a_collision_at_the_start() -> None:
    world = World.build(cylinders=[((0.5, 0.0), 0.2, 1.0)])
    stage = WorldStage(world, rate_hz=20.0)
    stage.start(7.0)
    assert stage.collision == "vehicle" and stage.collision_time_s == 7.0
    stage.handle(topics.WHEEL_COMMAND, _wheel(-0.5, 0.0), 7.0)
    assert _truth(stage, 8.0).x_m == 0.0
    assert stage.counters()["commands_ignored"] == 1


def test_minimum_clearance_is_kept_and_the_message_caps_it() -> None:
    # Driving along y = 0 past a cylinder at (3, 0.8) of radius 0.2: its surface comes within
    # 0.8 - 0.2 - 0.3 = 0.3 m of the left side, and only that close.
    world = World.build(cylinders=[((3.0, 0.8), 0.2, 1.0)])
    stage = WorldStage(world, rate_hz=20.0, command_timeout_s=100.0)
    stage.start(0.0)
    first = _truth(stage, 0.0)
    assert first.clearance_m == pytest.approx(math.hypot(2.6, 0.5) - 0.2)
    stage.handle(topics.WHEEL_COMMAND, _wheel(0.5, 0.0), 0.0)
    nearest = math.inf
    while (t := stage.next_tick_s() or 0.0) <= 14.0:
        truth = _truth(stage, t)
        nearest = min(nearest, truth.clearance_m)
        assert truth.min_clearance_m == pytest.approx(nearest, abs=1e-12)
    assert stage.min_clearance_m == pytest.approx(0.3, abs=1e-12)
    assert stage.collision == "" and math.isnan(stage.collision_time_s)
    assert stage.clearance_m > 2.0  # long past it
    # Nothing in the world: infinitely clear, reported as the cap.
    empty = WorldStage(World.build())
    empty.start(0.0)
    truth = _truth(empty, 0.0)
    assert math.isinf(empty.clearance_m)
    assert truth.clearance_m == truth.min_clearance_m == MAX_REPORTED_CLEARANCE_M


def test_every_tick_in_a_drive_agrees_with_the_footprint() -> None:
    """Turning through the crossing world with its movers: the clearance each message carries
    is the footprint's at the true pose with the movers at the stamp."""
    world = load_world(REPO / "worlds" / "crossing.toml")
    stage = WorldStage(world, rate_hz=20.0, command_timeout_s=100.0)
    stage.start(0.0)
    stage.handle(topics.WHEEL_COMMAND, _wheel(0.2, 0.3), 0.0)
    while (t := stage.next_tick_s() or 0.0) <= 6.0 and not stage.collision:
        truth = _truth(stage, t)
        expected, _ = outline_clearance(
            world, (truth.x_m, truth.y_m, truth.yaw_rad), truth.mover_xy, truth.mover_radius_m
        )
        assert truth.clearance_m == pytest.approx(expected, abs=1e-12)
        assert truth.min_clearance_m <= truth.clearance_m
