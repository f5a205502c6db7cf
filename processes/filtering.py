"""The filtering process: validation gates, segmentation, motion compensation.

Subscribes: ``calibrated_scan``, ``vehicle_state``. Publishes: ``filtered_scan``,
``heartbeat``. Parameters: ``calibration`` (file, for the noise current; empty: shipped),
``min_snr``, ``gate_chi2``, ``intensity_ratio_gate`` (see :mod:`agent.perception.filtering`).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from agent.stages.filtering_stage import FilteringStage
from processes.runtime import run_process

build = FilteringStage.from_params  # the stage from launch-file params (also used in lock-step)


def main(argv: Sequence[str] | None = None) -> int:
    return run_process(build, argv)


if __name__ == "__main__":
    sys.exit(main())
