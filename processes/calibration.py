"""The calibration process: raw scans to ranges with a per-sample σ.

Subscribes: ``raw_scan``. Publishes: ``calibrated_scan``, ``heartbeat``.
Parameters: ``calibration`` (file; empty for the shipped calibration).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from agent.stages.calibration_stage import CalibrationStage
from processes.runtime import run_process

build = CalibrationStage.from_params  # the stage from launch-file params (also used in lock-step)


def main(argv: Sequence[str] | None = None) -> int:
    return run_process(build, argv)


if __name__ == "__main__":
    sys.exit(main())
