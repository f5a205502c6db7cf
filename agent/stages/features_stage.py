"""The features stage: filtered scans to segments, corners, occluding edges and cylinders.

Inputs: ``filtered_scan``. Outputs: ``features``. See :mod:`agent.perception.features`.
"""

from __future__ import annotations

import numpy as np

from agent import perception
from agent.calibration.table import Calibration, load_default_calibration
from agent.perception.features import Feature, FeatureSettings, extract_features
from agent.runtime import topics
from agent.runtime.messages import Features, FilteredScan, Header, Message
from agent.runtime.stage import Output, Params, Stage
from agent.sensor.detection import sample_noise_correlation
from agent.sensor.params import nominal_sensor
from agent.stages.scan_checks import filtered_scan_problem

KIND_CODES = {"segment": 0, "corner": 1, "edge": 2, "cylinder": 3}


def features_message(found: list[Feature], header: Header, sweep_index: int) -> Features:
    """Pack features into the ``features`` message (struct of arrays, NaN-padded to 3)."""
    k = len(found)
    params = np.full((k, 3), np.nan)
    covariance = np.full((k, 3, 3), np.nan)
    endpoints = np.full((k, 2, 2), np.nan)
    side = np.zeros(k, dtype=np.int32)
    for i, f in enumerate(found):
        dof = f.params.size
        params[i, :dof] = f.params
        covariance[i, :dof, :dof] = f.covariance
        if f.endpoints is not None:
            endpoints[i] = f.endpoints
        if f.nearer_side is not None:
            side[i] = 1 if f.nearer_side == "left" else -1
    return Features(
        header=header,
        kind=np.array([KIND_CODES[f.kind] for f in found], dtype=np.uint8),
        params=params, covariance=covariance, endpoints=endpoints, nearer_side=side,
        reflectivity=np.array([f.reflectivity for f in found], dtype=np.float64),
        sweep_index=sweep_index,
    )  # fmt: skip


class FeaturesStage(Stage):
    """Extracts features from every filtered scan."""

    def __init__(
        self,
        signal_constant_Am2: float,
        noise_current_A: float | None = None,
        settings: FeatureSettings | None = None,
    ) -> None:
        self.signal_constant_Am2 = signal_constant_Am2
        self.noise_current_A = noise_current_A
        # The sensor's detection filter correlates neighbouring samples' noise.
        self.neighbour_correlation = float(sample_noise_correlation(nominal_sensor(), 1)[0])
        self.settings = settings if settings is not None else FeatureSettings()
        self._counts = {
            "scans": 0, "filtered_scan_malformed": 0, **{f"{kind}s": 0 for kind in KIND_CODES}
        }  # fmt: skip

    @classmethod
    def from_params(cls, params: Params) -> FeaturesStage:
        path = params.string("calibration", "")
        params.check_all_read()
        calibration = Calibration.load(path) if path else load_default_calibration()
        return cls(calibration.signal_constant_Am2, calibration.noise_current_A)

    def extract(self, scan: FilteredScan) -> list[Feature]:
        return extract_features(
            scan.points_xy, scan.covariance, scan.segment, scan.flag, scan.intensity_A,
            scan.range_m, scan.origin_xy, scan.scan_angle_rad, self.signal_constant_Am2,
            noise_current_A=self.noise_current_A,
            neighbour_correlation=self.neighbour_correlation, settings=self.settings,
        )  # fmt: skip

    def prepare(self) -> None:
        """Load the compiled kernels (about a third of a second, once per process)."""
        perception.warm_up()

    def start(self, now_s: float) -> list[Output]:
        # Before the first scan, once the process has joined the graph: upstream stages are
        # not held up meanwhile. A standby has done it already; then this costs nothing.
        self.prepare()
        return []

    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        if topic != topics.FILTERED_SCAN or not isinstance(msg, FilteredScan):
            return []
        if filtered_scan_problem(msg) is not None:
            self._counts["filtered_scan_malformed"] += 1
            return []
        found = self.extract(msg)
        self._counts["scans"] += 1
        for f in found:
            self._counts[f"{f.kind}s"] += 1
        header = Header(stamp_ns=msg.header.stamp_ns, frame_id=msg.header.frame_id)
        return [(topics.FEATURES, features_message(found, header, msg.sweep_index))]

    def counters(self) -> dict[str, int]:
        return dict(self._counts)
