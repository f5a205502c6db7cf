"""The drift ceiling tool: exact odometry reaches every goal; the default wheel errors do
not, over the metres of a random task."""

from __future__ import annotations

from agent.sim.odometry import OdometryErrorModel
from agent.sim.taskgen import random_tasks
from tests.unit.control.odometry_ceiling import task_ceiling


def test_exact_odometry_ends_on_the_goal_and_wheel_errors_do_not() -> None:
    ((world, task),) = random_tasks(1, 0)
    exact = OdometryErrorModel(scale_sigma=0.0, ratio_sigma=0.0, track_sigma=0.0, slip_m=0.0)
    c = task_ceiling(world, task, exact, vehicles=4, seed=0)
    assert c is not None
    assert c.median_error_m < 1e-6
    assert c.within == 1.0 or task.kind == "dock"
    drifting = task_ceiling(world, task, OdometryErrorModel(), vehicles=200, seed=0)
    assert drifting is not None
    # 1.7°/m of heading drift (RMS) over a path of several metres: tens of centimetres.
    assert drifting.median_error_m > 0.1
