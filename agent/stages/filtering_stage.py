"""The filtering stage: calibrated scans to validated, motion-compensated points.

Inputs: ``calibrated_scan``, ``vehicle_state`` (the vehicle's odometry, for placing each
sample at its own time). Outputs: ``filtered_scan``. See :mod:`agent.perception.filtering`.
"""

from __future__ import annotations

import numpy as np

from agent import perception
from agent.calibration.table import Calibration, load_default_calibration
from agent.perception.filtering import (
    FilterSettings,
    PoseHistory,
    SampleFlag,
    gate_and_segment,
    place_samples,
)
from agent.runtime import topics
from agent.runtime.messages import CalibratedScan, FilteredScan, Header, Message, VehicleState
from agent.runtime.stage import Output, Params, Stage
from agent.sensor.params import nominal_sensor


class FilteringStage(Stage):
    """Gates, segmentation and motion compensation for every calibrated scan.

    Parameters
    ----------
    noise_current_A
        The characterised ``I_n`` (from the calibration) for the signal-to-noise gate.
    settings
        The gates (:class:`agent.perception.filtering.FilterSettings`).
    mount_offset_m
        Centre of scanning ahead of the vehicle's base origin.
    """

    def __init__(
        self,
        noise_current_A: float,
        settings: FilterSettings | None = None,
        mount_offset_m: float | None = None,
    ) -> None:
        self.noise_current_A = noise_current_A
        self.settings = settings if settings is not None else FilterSettings()
        self.mount_offset_m = (
            nominal_sensor().mount_offset_m if mount_offset_m is None else mount_offset_m
        )
        self.poses = PoseHistory()
        self._counts = {"scans": 0, "uncompensated": 0}
        self._flags = np.zeros(len(SampleFlag), dtype=np.int64)

    @classmethod
    def from_params(cls, params: Params) -> FilteringStage:
        path = params.string("calibration", "")
        calibration = Calibration.load(path) if path else load_default_calibration()
        settings = FilterSettings(
            min_snr=params.number("min_snr", 20.0, lo=1.0),
            gate_chi2=params.number("gate_chi2", 16.0, lo=1.0),
            intensity_ratio_gate=params.number("intensity_ratio_gate", 1.3, lo=1.01),
        )
        params.check_all_read()
        return cls(calibration.noise_current_A, settings)

    def start(self, now_s: float) -> list[Output]:
        # Load the compiled kernels (about a third of a second) before the first scan, once
        # the process has joined the graph: upstream stages are not held up meanwhile.
        perception.warm_up()
        return []

    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        if topic == topics.VEHICLE_STATE and isinstance(msg, VehicleState):
            self.poses.add(
                msg.header.stamp_s, msg.x_m, msg.y_m, msg.yaw_rad, msg.speed_m_s, msg.yaw_rate_rad_s
            )
            return []
        if topic == topics.CALIBRATED_SCAN and isinstance(msg, CalibratedScan):
            return [(topics.FILTERED_SCAN, self.filter(msg))]
        return []

    def filter(self, scan: CalibratedScan) -> FilteredScan:
        """Filter one calibrated scan (see :mod:`agent.perception.filtering`)."""
        st = self.settings
        flags, segment = gate_and_segment(
            scan.range_m, scan.sigma_m, scan.intensity_A, self.noise_current_A, st
        )
        reference = float(scan.time_s[-1]) if scan.time_s.size else scan.header.stamp_s
        placed = place_samples(
            scan.time_s,
            scan.scan_angle_rad,
            scan.pan_rad,
            scan.range_m,
            scan.sigma_m,
            scan.scan_angle_sigma_rad,
            self.poses,
            reference,
            self.mount_offset_m,
        )
        compensated = len(self.poses) > 0
        self._counts["scans"] += 1
        self._counts["uncompensated"] += not compensated
        self._flags += np.bincount(flags, minlength=len(SampleFlag))
        return FilteredScan(
            header=Header(stamp_ns=round(reference * 1e9), frame_id="base_link"),
            points_xy=placed.points_xy, covariance=placed.covariance,
            origin_xy=placed.origin_xy, scan_angle_rad=scan.scan_angle_rad,
            intensity_A=scan.intensity_A, range_m=scan.range_m, sigma_m=scan.sigma_m,
            flag=flags, segment=segment, sweep_index=scan.sweep_index,
            motion_compensated=compensated,
        )  # fmt: skip

    def counters(self) -> dict[str, int]:
        flags = {f"samples_{f.name.lower()}": int(self._flags[f]) for f in SampleFlag}
        return {**self._counts, **flags}
