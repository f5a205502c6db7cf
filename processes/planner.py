"""The planner process: the environment vector for the vehicle, and the head's policy.

Subscribes: ``tracks``, ``filtered_scan``, ``vehicle_state``, ``head_state``. Publishes:
``environment``, ``head_command``, ``heartbeat``. Parameters: ``policy`` (``forward`` or
``sweep``), ``valid_for_s``, ``stale_after_s``, ``idle_period_s``, ``docking_reflectivity``,
``free_space_max_age_s``, ``mover_speed_m_s``, ``sweep_step_deg``, ``sweep_dwell_sweeps``,
``resend_after_s`` (see :class:`agent.stages.planner_stage.PlannerStage`).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from agent.stages.planner_stage import PlannerStage
from processes.runtime import run_process

build = PlannerStage.from_params  # the stage from launch-file params (also used in lock-step)


def main(argv: Sequence[str] | None = None) -> int:
    return run_process(build, argv)


if __name__ == "__main__":
    sys.exit(main())
