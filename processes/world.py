"""The world simulator process: owns ground truth (obstacles, movers, the vehicle's true
pose) and the base's drifting wheel odometry.

Subscribes: ``wheel_command``. Publishes: ``odometry``, ``world_truth``, ``heartbeat``.
Parameters: ``world`` (file), ``rate_hz``, ``command_timeout_s``, ``max_speed_m_s``,
``max_yaw_rate_rad_s``, ``seed``, ``wheel_track_m``, ``wheel_scale_sigma``,
``wheel_ratio_sigma``, ``wheel_track_sigma``, ``wheel_slip_m`` (see
:class:`agent.stages.world_stage.WorldStage`).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from agent.stages.world_stage import WorldStage
from processes.runtime import run_process

build = WorldStage.from_params  # the stage from launch-file params (also used in lock-step)


def main(argv: Sequence[str] | None = None) -> int:
    return run_process(build, argv)


if __name__ == "__main__":
    sys.exit(main())
