"""The controller's safety rules: the stop on a missing, stale or untrusted vector, and never
faster than it can stop within the space the profile knows clear."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.control.clearance import max_scale
from agent.control.controller import Controller, ControllerSettings
from agent.control.view import EnvironmentView, unusable_reason
from agent.kinematics.vehicle import VehicleSpec
from agent.task import Task
from tests.unit.control.harness import Harness, Scene

SPEC = VehicleSpec()
SETTINGS = ControllerSettings()


def view(
    stamp_s: float, free_m: float = 2.5, sensor_ok: bool = True, valid_for_s: float = 0.3
) -> EnvironmentView:
    """No obstacles; the forward window (±20°) clear to ``free_m`` from the centre of
    scanning."""
    bearings = np.radians(np.arange(-180, 180, dtype=np.float64))
    ranges = np.where(np.abs(bearings) <= math.radians(20.0) + 1e-9, free_m, 0.0)
    return EnvironmentView(
        stamp_s=stamp_s, valid_for_s=valid_for_s, sensor_ok=sensor_ok,
        obstacle_id=np.zeros(0, dtype=np.int64), kind=np.zeros(0, dtype=np.uint8),
        position_xy=np.zeros((0, 2)), velocity_xy=np.zeros((0, 2)),
        covariance=np.zeros((0, 4, 4)), extent=np.zeros((0, 4)), reflectivity=np.zeros(0),
        free_bearing_rad=bearings, free_range_m=ranges,
    )  # fmt: skip


def odometry(ctl: Controller, t: float, x: float = 0.0, v: float = 0.0) -> None:
    ctl.update_odometry(t, np.array([x, 0.0, 0.0]), np.eye(3) * 1e-6, v, 0.0)


NO_LOOK = ControllerSettings(look_at_start=False)


def test_stops_until_a_fresh_trusted_vector_and_resumes_on_one() -> None:
    ctl = Controller(Task("goto", (5.0, 0.0)), settings=NO_LOOK)
    assert ctl.command(0.0).reason == "no_odometry"
    odometry(ctl, 0.0)
    out = ctl.command(0.05)
    assert (out.speed_m_s, out.yaw_rate_rad_s, out.mode, out.reason) == (
        0.0, 0.0, "waiting", "no_environment",
    )  # fmt: skip
    ctl.update_environment(view(0.1))
    odometry(ctl, 0.1)
    moving = ctl.command(0.1)
    assert moving.speed_m_s > 0.0 and moving.mode == "driving"
    # The newest vector is untrusted: stop, although an older one would still be valid.
    ctl.update_environment(view(0.15, sensor_ok=False))
    out = ctl.command(0.15)
    assert (out.speed_m_s, out.yaw_rate_rad_s, out.reason) == (0.0, 0.0, "sensor_not_ok")
    # Trusted again, but past its validity at the command: stop.
    ctl.update_environment(view(0.2))
    stale = ctl.command(0.2 + 0.3 + 1e-6)
    assert (stale.speed_m_s, stale.yaw_rate_rad_s, stale.reason) == (0.0, 0.0, "stale_environment")
    # Older vectors do not replace the newest.
    ctl.update_environment(view(0.19))
    assert ctl.command(0.55).reason == "stale_environment"
    ctl.update_environment(view(0.6))
    odometry(ctl, 0.6)
    assert ctl.command(0.6).speed_m_s > 0.0


@pytest.mark.parametrize(
    ("stamp", "now", "ok", "reason"),
    [(1.0, 1.0, True, ""), (1.0, 1.3, True, ""), (1.0, 1.3001, True, "stale_environment"),
     (1.0, 0.999, True, "stale_environment"), (1.0, 1.1, False, "sensor_not_ok")],
)  # fmt: skip
def test_a_vector_is_usable_only_from_its_stamp_for_valid_for_s(
    stamp: float, now: float, ok: bool, reason: str
) -> None:
    assert unusable_reason(view(stamp, sensor_ok=ok), now) == reason


def test_the_closed_loop_stops_when_vectors_stop_or_turn_untrusted() -> None:
    h = Harness(Scene(), Task("goto", (12.0, 0.0)))
    h.run(10.0)  # the look round at the start takes about 7 s
    assert h.v > 0.3
    h.deliver_vectors = False
    h.run(10.0 + 0.3 + 0.05 + 0.01)  # validity, then the next command
    assert h.command == (0.0, 0.0)
    h.deliver_vectors = True
    h.sensor_ok = False
    h.run(11.0)
    assert h.command == (0.0, 0.0) and h.record.outputs[-1].reason == "sensor_not_ok"
    h.sensor_ok = True
    h.run(12.0)
    assert h.v > 0.1


def test_max_scale_meets_the_braking_envelope_exactly_when_it_limits() -> None:
    rng = np.random.default_rng(7)
    v = rng.uniform(-0.5, 0.5, 200)
    w = rng.uniform(-1.5, 1.5, 200)
    d_free = rng.uniform(0.0, 1.0, 200)
    tau, margin = 0.1, 0.025
    lam = max_scale(v, w, d_free, SPEC, tau, margin)
    u = lam * (np.abs(v) + SPEC.circumradius_m * np.abs(w))
    t_brake = lam * np.maximum(np.abs(v) / SPEC.max_accel_m_s2, np.abs(w) / 2.0)
    envelope = u * (tau + 0.5 * t_brake) + margin
    limited = lam < 1.0
    assert ((lam >= 0.0) & (lam <= 1.0)).all()
    np.testing.assert_allclose(envelope[limited & (d_free > margin)],
                               d_free[limited & (d_free > margin)], atol=1e-12)  # fmt: skip
    assert (envelope[~limited] <= d_free[~limited] + 1e-12).all()
    assert (lam[d_free <= margin] == 0.0).all()


@pytest.mark.parametrize("free_m", [0.3, 0.45, 0.6, 1.0, 2.5])
def test_speed_never_exceeds_what_the_known_free_distance_allows(free_m: float) -> None:
    """Standing at the origin facing the goal, the window clear to ``free_m`` from the centre
    of scanning (0.1 m behind the bumper), no obstacles, the start's disc 0.92 m about the
    centre: each command's speed, held one period plus the latency and then braked, stops
    the bumper within the known free distance less the margin: what the profile vouches for
    ahead, or the start's disc (the sensor cannot see nearer than its near limit). Its
    odometry does not move, so nothing else is ever known. A profile that ends within
    1.5 m ends at a possible surface: the vehicle may turn away rather than drive."""
    settings = ControllerSettings(look_at_start=False)
    ctl = Controller(Task("goto", (20.0, 0.0)), settings=settings)
    t, v = 0.0, 0.0
    speeds, turns = [], []
    for _ in range(60):
        odometry(ctl, t, v=v)
        ctl.update_environment(view(t, free_m))
        out = ctl.command(t)
        v = out.speed_m_s
        speeds.append(v)
        turns.append(out.yaw_rate_rad_s)
        t += SETTINGS.period_s
    s = np.array(speeds)
    tau = SETTINGS.period_s + SETTINGS.latency_s
    free_ahead = free_m - (0.5 * SPEC.length_m - SPEC.head_offset_m)
    disc_ahead = SPEC.circumradius_m + settings.start_clear_m - 0.5 * SPEC.length_m
    known = max(free_ahead, disc_ahead)
    stop = s * tau + s**2 / (2 * SPEC.max_accel_m_s2)
    assert (stop + SETTINGS.stop_margin_m <= known + 1e-9).all()
    if free_m >= SETTINGS.suspect_max_range_m:
        assert s[-1] > 0.1  # ... and drives
    else:
        assert s[-1] > 0.1 or abs(turns[-1]) > 0.1  # ... or turns away


def test_in_the_closed_loop_it_never_outruns_the_space_ahead() -> None:
    """A corridor (1.6 m wide) closed by a box, seen only from 2.5 m, the goal beyond it: at
    every command on a nearly straight course, the braking distance fits in the gap between
    the bumper and the box along the heading (the dead end itself: the escape test's)."""
    scene = Scene(segments=[((-1.0, 0.8), (5.2, 0.8)), ((-1.0, -0.8), (5.2, -0.8))])
    scene.box(5.0, 0.0, 0.4, 1.6)
    h = Harness(scene, Task("goto", (8.0, 0.0)))
    rec = h.run(30.0, stop_on_arrival=False)
    assert not rec.collided
    tau = SETTINGS.period_s + SETTINGS.latency_s
    checked = 0
    for pose, out in zip(rec.pose, rec.outputs, strict=True):
        v = out.speed_m_s
        if abs(out.yaw_rate_rad_s) > 0.1 or v <= 0.0:
            continue
        x, y, yaw = pose
        corners = [(0.4, 0.3), (0.4, 0.0), (0.4, -0.3)]
        starts = np.array(
            [
                [
                    x + cx * math.cos(yaw) - cy * math.sin(yaw),
                    y + cx * math.sin(yaw) + cy * math.cos(yaw),
                ]
                for cx, cy in corners
            ]
        )
        gap = min(float(h.cast(p, np.array([yaw]), 0.0)[0][0]) for p in starts)
        assert v * tau + v * v / (2 * SPEC.max_accel_m_s2) <= gap
        checked += gap < 2.5
    assert checked >= 2  # the box was ahead, within the sensor's reach


def test_bad_input_is_refused_with_one_clear_line() -> None:
    with pytest.raises(ValueError, match="planner"):
        Controller(Task("goto", (1.0, 0.0)), planner="astar")  # type: ignore[arg-type]
    ctl = Controller(Task("goto", (1.0, 0.0)))
    with pytest.raises(ValueError, match="pose must be"):
        ctl.update_odometry(0.0, np.zeros(2), np.eye(3), 0.0, 0.0)
    with pytest.raises(ValueError, match="finite"):
        ctl.update_odometry(0.0, np.array([0.0, np.nan, 0.0]), np.eye(3), 0.0, 0.0)
    good = view(0.0)
    with pytest.raises(ValueError, match="free_bearing_rad must be a uniform grid"):
        EnvironmentView(**{**good.__dict__, "free_bearing_rad": good.free_bearing_rad + 0.1})
    with pytest.raises(ValueError, match=r"position_xy must be \(0, 2\)"):
        EnvironmentView(**{**good.__dict__, "position_xy": np.zeros((1, 2))})
    with pytest.raises(ValueError, match=r"ControllerSettings\.period_s"):
        ControllerSettings(period_s=0.0)
