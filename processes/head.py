"""The head process: pan, scan window, laser safety, raw scans, over one of two backends.

Subscribes: ``head_command``, ``world_truth``. Publishes: ``raw_scan``, ``head_state``,
``heartbeat``. Parameters: ``backend`` (``"sim"``, the default, or ``"serial"``); for the
simulated head ``world`` (file), ``seed``, ``watchdog_s``
(:class:`agent.stages.head_stage.HeadStage`); for a head on a serial line ``port`` (a device
path) and ``baud`` (921,600) (:class:`agent.stages.serial_head_stage.SerialHeadStage`,
``docs/head-protocol.md``).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from agent.runtime.stage import Params, Stage
from agent.stages.head_stage import HeadStage
from agent.stages.serial_head_stage import SerialHeadStage
from processes.runtime import run_process


class PySerialPort:
    """The serial backend's transport: pyserial, non-blocking (``SerialException`` is an
    ``OSError``: the stage reopens the port when it is raised)."""

    def __init__(self, port: str, baud: int) -> None:
        import serial

        self.port = serial.Serial(port, baud, timeout=0, write_timeout=0.5)

    def read(self) -> bytes:
        waiting = self.port.in_waiting
        return bytes(self.port.read(waiting)) if waiting else b""

    def write(self, data: bytes) -> None:
        self.port.write(data)

    def close(self) -> None:
        self.port.close()


def build(params: Params, name: str = "head") -> Stage:
    """The stage from launch-file params (the simulated head also runs in lock-step)."""
    backend = params.string("backend", "sim")
    if backend == "serial":
        stage = SerialHeadStage.from_params(params, PySerialPort, name=name)
        params.check_all_read()
        return stage
    if backend != "sim":
        raise ValueError(f"{params.process}: backend must be 'sim' or 'serial', got {backend!r}")
    return HeadStage.from_params(params, name=name)


def main(argv: Sequence[str] | None = None) -> int:
    return run_process(build, argv)


if __name__ == "__main__":
    sys.exit(main())
