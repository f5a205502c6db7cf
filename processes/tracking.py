"""The tracking process: feature tracks in ``odom``.

Subscribes: ``features``, ``filtered_scan``, ``vehicle_state``. Publishes: ``tracks``,
``heartbeat``. Parameters: ``gate_probability``, ``confirm_hits``, ``confirm_window``,
``delete_misses``, ``max_coast_moving_s``, ``cv_accel_psd_m2_s3``, ``max_state_age_s``.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from agent.stages.tracking_stage import TrackingStage
from processes.runtime import run_process

build = TrackingStage.from_params  # the stage from launch-file params (also used in lock-step)


def main(argv: Sequence[str] | None = None) -> int:
    return run_process(build, argv)


if __name__ == "__main__":
    sys.exit(main())
