"""The features process: segments, corners, occluding edges and cylinders.

Subscribes: ``filtered_scan``. Publishes: ``features``,
``heartbeat``. Parameters: ``calibration`` (file, for the signal constant S; empty: shipped).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from agent.stages.features_stage import FeaturesStage
from processes.runtime import run_process

build = FeaturesStage.from_params  # the stage from launch-file params (also used in lock-step)


def main(argv: Sequence[str] | None = None) -> int:
    return run_process(build, argv)


if __name__ == "__main__":
    sys.exit(main())
