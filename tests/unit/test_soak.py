"""The soak's judgement of wheel commands against the vectors' validity (cli.soak): a
command that would move the vehicle after the newest vector went stale is counted."""

from __future__ import annotations

import numpy as np

from agent.runtime.messages import EnvironmentVector, Header, WheelCommand, stamp_ns
from cli.soak import _Watch


def _vector(t: float) -> EnvironmentVector:
    return EnvironmentVector(
        header=Header(stamp_ns=stamp_ns(t), frame_id="odom"), obstacle_id=np.zeros(0, np.int64),
        kind=np.zeros(0, np.uint8), position_xy=np.zeros((0, 2)), velocity_xy=np.zeros((0, 2)),
        covariance=np.zeros((0, 4, 4)), extent=np.zeros((0, 4)), reflectivity=np.zeros(0),
        free_bearing_rad=np.zeros(0), free_range_m=np.zeros(0), sensor_ok=True, valid_for_s=0.3,
    )  # fmt: skip


def _command(t: float, v: float) -> WheelCommand:
    return WheelCommand(header=Header(stamp_ns=stamp_ns(t)), speed_m_s=v, yaw_rate_rad_s=0.0)


def test_commands_that_move_on_stale_vectors_are_counted() -> None:
    watch = _Watch(None)
    watch.take(_vector(10.0))  # valid to 10.3 s (+ 50 ms of transport)
    watch.take(_command(10.30, 0.2))  # fresh enough
    watch.take(_command(10.40, 0.0))  # stale, but stopped: right
    watch.take(_command(10.45, 0.1))  # stale and moving: wrong
    watch.take(_vector(10.5))
    watch.take(_command(10.55, 0.3))  # fresh again
    assert watch.moved_on_stale == 1 and watch.commands == 4 and watch.trusted == 2
    assert abs(watch.stale_s - 0.15) < 1e-9  # from 10.40 to the first fresh command
