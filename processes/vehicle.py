"""The vehicle controller process: drives the vehicle on the environment vector alone.

Subscribes: ``odometry``, ``environment``. Publishes: ``vehicle_state``, ``wheel_command``,
``heartbeat``. Parameters: ``world`` (the world file whose ``[task]`` to do), ``planner``
(``default`` or ``dwa``), ``rate_hz``, ``odometry_timeout_s`` (see
:class:`agent.stages.vehicle_stage.VehicleStage`).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from agent.stages.vehicle_stage import VehicleStage
from processes.runtime import run_process

build = VehicleStage.from_params  # the stage from launch-file params (also used in lock-step)


def main(argv: Sequence[str] | None = None) -> int:
    return run_process(build, argv)


if __name__ == "__main__":
    sys.exit(main())
