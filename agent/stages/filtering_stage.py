"""The filtering stage: calibrated scans to validated, motion-compensated points.

Inputs: ``calibrated_scan``, ``vehicle_state`` (the vehicle's odometry, for placing each
sample at its own time). Outputs: ``filtered_scan``. See :mod:`agent.perception.filtering`.

Motion compensation fails closed (:mod:`agent.perception.filtering.placement`): a scan with a
sample more than ``max_state_age_s`` from the vehicle state its pose is reckoned from, or
with no state at all, leaves uncompensated (``motion_compensated`` false: every point in
``base_link`` at the scan's end, no motion model). Counters, in the heartbeat:

* ``scans``; ``uncompensated`` of them, split into ``uncompensated_no_vehicle_state`` (none
  had arrived) and ``uncompensated_stale_pose`` (past ``max_state_age_s``);
* ``vehicle_state_out_of_order`` and ``vehicle_state_duplicate``: states dropped for a stamp
  older than, or equal to, the newest held;
* ``samples_<flag>``: samples by :class:`agent.perception.filtering.SampleFlag`.
"""

from __future__ import annotations

import math

import numpy as np

from agent import perception
from agent.arrays import wrap_angle
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

MAX_STATE_AGE_S = 0.3  # s; the default of FilteringStage's max_state_age_s (why: there)


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
    max_state_age_s
        Launch parameter: the longest a sample may be from the vehicle state its pose is
        reckoned from (by stamps and sample times, not the clock) for the scan to be
        motion-compensated. The default, 0.3 s, is three periods of the slowest
        ``vehicle_state`` a controller may send (10 Hz, ``docs/interface.md``): one lost
        state plus 0.1 s of latency still pass, while a stopped stream turns compensation
        off within 0.3 s instead of extrapolating its last pose on and on.
    """

    def __init__(
        self,
        noise_current_A: float,
        settings: FilterSettings | None = None,
        mount_offset_m: float | None = None,
        max_state_age_s: float = MAX_STATE_AGE_S,
    ) -> None:
        if not (math.isfinite(max_state_age_s) and max_state_age_s >= 0):
            raise ValueError(f"max_state_age_s must be finite and >= 0, got {max_state_age_s}")
        self.noise_current_A = noise_current_A
        self.max_state_age_s = max_state_age_s
        self.settings = settings if settings is not None else FilterSettings()
        self.mount_offset_m = (
            nominal_sensor().mount_offset_m if mount_offset_m is None else mount_offset_m
        )
        self.poses = PoseHistory()
        self._counts = {
            "scans": 0,
            "uncompensated": 0,
            "uncompensated_no_vehicle_state": 0,
            "uncompensated_stale_pose": 0,
        }
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
        max_state_age_s = params.number("max_state_age_s", MAX_STATE_AGE_S, lo=0.0, hi=1.0)
        params.check_all_read()
        return cls(calibration.noise_current_A, settings, max_state_age_s=max_state_age_s)

    def prepare(self) -> None:
        """Load the compiled kernels (about a third of a second, once per process)."""
        perception.warm_up()

    def start(self, now_s: float) -> list[Output]:
        # Before the first scan, once the process has joined the graph: upstream stages are
        # not held up meanwhile. A standby has done it already; then this costs nothing.
        self.prepare()
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
            self.max_state_age_s,
        )
        compensated = placed.motion_compensated
        self._counts["scans"] += 1
        if not compensated:
            self._counts["uncompensated"] += 1
            why = "stale_pose" if len(self.poses) else "no_vehicle_state"
            self._counts[f"uncompensated_{why}"] += 1
        self._flags += np.bincount(flags, minlength=len(SampleFlag))
        return FilteredScan(
            header=Header(stamp_ns=round(reference * 1e9), frame_id="base_link"),
            points_xy=placed.points_xy, covariance=placed.covariance,
            origin_xy=placed.origin_xy, scan_angle_rad=scan.scan_angle_rad,
            intensity_A=scan.intensity_A, range_m=scan.range_m, sigma_m=scan.sigma_m,
            flag=flags, segment=segment, sweep_index=scan.sweep_index,
            motion_compensated=compensated, beam_rad=wrap_angle(placed.beam_heading_rad),
        )  # fmt: skip

    def counters(self) -> dict[str, int]:
        flags = {f"samples_{f.name.lower()}": int(self._flags[f]) for f in SampleFlag}
        states = {
            "vehicle_state_out_of_order": self.poses.out_of_order,
            "vehicle_state_duplicate": self.poses.duplicates,
        }
        return {**self._counts, **states, **flags}
