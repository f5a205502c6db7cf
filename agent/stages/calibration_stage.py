"""The calibration stage: raw scans to ranges with a per-sample σ.

Inputs: ``raw_scan``. Outputs: ``calibrated_scan``.
"""

from __future__ import annotations

from agent.calibration.table import Calibration, load_default_calibration
from agent.runtime import topics
from agent.runtime.messages import CalibratedScan, Header, Message, RawScan
from agent.runtime.stage import Output, Params, Stage
from agent.sensor.samples import RawSamples


class CalibrationStage(Stage):
    """Applies a :class:`~agent.calibration.table.Calibration` to every raw scan."""

    def __init__(self, calibration: Calibration) -> None:
        self.calibration = calibration
        self._scans = 0

    @classmethod
    def from_params(cls, params: Params) -> CalibrationStage:
        path = params.string("calibration", "")
        params.check_all_read()
        return cls(Calibration.load(path) if path else load_default_calibration())

    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        if topic != topics.RAW_SCAN or not isinstance(msg, RawScan):
            return []
        self._scans += 1
        out = self.calibrated_message(msg, msg.header.stamp_ns, msg.sweep_index)
        return [(topics.CALIBRATED_SCAN, out)]

    def calibrated_message(
        self, raw: RawSamples, stamp_ns: int, sweep_index: int
    ) -> CalibratedScan:
        """Calibrate raw samples into a ``calibrated_scan`` message."""
        scan = self.calibration.calibrate_scan(raw)
        return CalibratedScan(
            header=Header(stamp_ns=stamp_ns, frame_id="head"),
            time_s=scan.time_s, scan_angle_rad=scan.scan_angle_rad, pan_rad=scan.pan_rad,
            image_position_norm=scan.image_position_norm, intensity_A=scan.intensity_A,
            range_m=scan.range_m, sigma_m=scan.sigma_m, direction=scan.direction,
            sweep_index=sweep_index,
            scan_angle_sigma_rad=self.calibration.scan_angle_sigma_rad,
        )  # fmt: skip

    def counters(self) -> dict[str, int]:
        return {"scans": self._scans}
