"""The head process with its simulated backend: pan, scan window, laser safety, raw scans.

Subscribes: ``head_command``, ``world_truth``. Publishes: ``raw_scan``, ``head_state``,
``heartbeat``. Parameters: ``world`` (file), ``seed``, ``watchdog_s`` (see
:class:`agent.stages.head_stage.HeadStage`).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from agent.stages.head_stage import HeadStage
from processes.runtime import run_process

build = HeadStage.from_params  # the stage from launch-file params (also used in lock-step)


def main(argv: Sequence[str] | None = None) -> int:
    return run_process(build, argv)


if __name__ == "__main__":
    sys.exit(main())
