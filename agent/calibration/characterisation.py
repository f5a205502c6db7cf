"""The chapter's characterisation (section 6.6), run against the simulated head.

:func:`characterise`: a cardboard target on axis at 0.75-2.5 m, N stares at each range, least
squares on logarithmic plots for ``S`` (eq. 6.10), ``I_n`` (eq. 6.14) and ``T`` hence ``fd``
(eq. 6.19-6.20); noise density against its theoretical value (eq. 6.16-6.18); Table 1; and the
accuracy at the ±20° scan edges relative to the centre.

Targets are placed in a head-centred world (:mod:`agent.sim.targets`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats

from agent.arrays import FloatArray
from agent.calibration.progress import Progress
from agent.calibration.table import Calibration
from agent.sensor.params import SensorParameters, theoretical_noise_density
from agent.sim.simulator import SensorSimulator
from agent.sim.targets import head_centred_pose, plane_world, tilted_target_world
from agent.sim.world import World

# Table 1 of the chapter: range (m) and standard deviation of range (cm).
PAPER_TABLE_1: tuple[tuple[float, float], ...] = (
    (0.75, 0.05), (1.0, 0.148), (1.25, 0.463), (1.5, 0.798),
    (1.75, 1.568), (2.0, 2.547), (2.25, 3.713), (2.5, 7.662),
)  # fmt: skip
CHARACTERISATION_RANGES_M: tuple[float, ...] = tuple(r for r, _ in PAPER_TABLE_1)


@dataclass(frozen=True)
class LogFit:
    """Least squares on a log-log plot: ``log10 y = slope·log10 r + intercept``."""

    slope: float
    intercept: float
    slope_stderr: float

    @property
    def constant(self) -> float:
        """The intercept at r = 1 m, as a value: ``10**intercept``."""
        return float(10.0**self.intercept)


def log_fit(ranges_m: FloatArray, values: FloatArray) -> LogFit:
    """Fit a straight line to ``log10(values)`` against ``log10(ranges_m)`` (scipy.stats)."""
    res = stats.linregress(np.log10(ranges_m), np.log10(values))
    return LogFit(float(res.slope), float(res.intercept), float(res.stderr))


@dataclass(frozen=True)
class CharacterisationResult:
    """Everything section 6.6-6.7 measures, and the raw data behind the figures."""

    true_S_Am2: float
    true_I_n_A: float
    true_fd_m2: float
    ranges_m: FloatArray
    mean_signal_A: FloatArray
    position_sd: FloatArray
    range_sd_m: FloatArray
    signal_fit: LogFit
    position_fit: LogFit
    range_fit: LogFit
    fit_S_Am2: float
    fit_I_n_A: float
    fit_T_per_m3: float
    fit_fd_m2: float
    measured_density_A_per_rtHz: float
    theoretical_density_A_per_rtHz: float
    bandwidth_hz: float
    detector_length_m: float
    edge_accuracy: dict[str, float]
    histogram_range_m: float
    histogram_samples_m: FloatArray

    @property
    def percent_above_theoretical(self) -> float:
        return 100.0 * (
            self.measured_density_A_per_rtHz / self.theoretical_density_A_per_rtHz - 1.0
        )

    def table(self) -> list[dict[str, float]]:
        paper = dict(PAPER_TABLE_1)
        return [
            {
                "range_m": float(r),
                "sd_cm": float(100 * s),
                "sd_pct": float(100 * s / r),
                "paper_sd_cm": paper.get(round(float(r), 2), math.nan),
            }
            for r, s in zip(self.ranges_m, self.range_sd_m, strict=True)
        ]

    def predicted_sd_m(self, ranges_m: FloatArray, density_A_per_rtHz: float) -> FloatArray:
        """Eq. 6.19-6.20 with a given noise density: ``T·z⁴``, ``T = P·I_n/(2·fd·S)``."""
        noise = density_A_per_rtHz * math.sqrt(self.bandwidth_hz)
        T = self.detector_length_m * noise / (2.0 * self.fit_fd_m2 * self.fit_S_Am2)
        return np.asarray(T * np.asarray(ranges_m) ** 4)

    def as_dict(self) -> dict[str, Any]:
        return {
            "true": {"S_Am2": self.true_S_Am2, "I_n_A": self.true_I_n_A, "fd_m2": self.true_fd_m2},
            "fit": {
                "S_Am2": self.fit_S_Am2,
                "I_n_A": self.fit_I_n_A,
                "fd_m2": self.fit_fd_m2,
                "T_per_m3": self.fit_T_per_m3,
                "slope_signal": self.signal_fit.slope,
                "slope_position": self.position_fit.slope,
                "slope_range": self.range_fit.slope,
            },
            "noise": {
                "measured_density_A_per_rtHz": self.measured_density_A_per_rtHz,
                "theoretical_density_A_per_rtHz": self.theoretical_density_A_per_rtHz,
                "percent_above_theoretical": self.percent_above_theoretical,
            },
            "table": self.table(),
            "edge_to_centre_accuracy": self.edge_accuracy["ratio"],
            "edge_accuracy": self.edge_accuracy,
            "errors": {
                "S_pct": 100 * (self.fit_S_Am2 / self.true_S_Am2 - 1),
                "I_n_pct": 100 * (self.fit_I_n_A / self.true_I_n_A - 1),
                "fd_pct": 100 * (self.fit_fd_m2 / self.true_fd_m2 - 1),
            },
        }


def _stare_at(
    world: World,
    head: SensorParameters,
    rng: np.random.Generator,
    calibration: Calibration,
    scan_angle_rad: float,
    n_samples: int,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    sim = SensorSimulator(world, head, rng)
    raw, _ = sim.stare(scan_angle_rad, n_samples, trajectory=head_centred_pose(head))
    scan = calibration.calibrate_scan(raw)
    return scan.intensity_A, scan.image_position_norm, scan.range_m


def characterise(
    calibration: Calibration,
    head: SensorParameters,
    rng: np.random.Generator,
    n_samples: int = 1000,
    ranges_m: Sequence[float] = CHARACTERISATION_RANGES_M,
    edge_range_m: float = 1.0,
    progress: Progress | None = None,
) -> CharacterisationResult:
    """Section 6.6-6.7 on the simulated head, ranges from ``calibration``'s table.

    Edge accuracy follows section 6.7.2: the target at ``edge_range_m`` at ±20°, held at the
    orientation it has on axis (facing along the sensor axis, as a wall ahead would), so both
    the aperture (cos θ) and the Lambertian viewing angle (cos θ) reduce the signal while the
    triangulation gain along the beam falls with cos θ: about cos³θ = 0.83 overall. The ratio is
    the centre's σ over the mean σ of the two edges (the ``(d/2)·sin 2θ`` term of eq. 6.5 makes
    one edge better than the other).
    """
    if n_samples < 10:
        raise ValueError(f"n_samples must be at least 10, got {n_samples}")
    ranges = np.asarray(ranges_m, dtype=np.float64)
    mean_signal, pos_sd, range_sd = (np.empty(ranges.size) for _ in range(3))
    histogram = np.empty(0)
    total = ranges.size + 3
    for i, r in enumerate(ranges):
        s, u, rng_m = _stare_at(plane_world(float(r)), head, rng, calibration, 0.0, n_samples)
        mean_signal[i] = np.mean(s)
        pos_sd[i] = np.nanstd(u, ddof=1)
        range_sd[i] = np.nanstd(rng_m, ddof=1)
        if math.isclose(r, 1.0):
            histogram = rng_m[np.isfinite(rng_m)]
        if progress is not None:
            progress(i + 1, total)
    signal_fit = log_fit(ranges, mean_signal)
    position_fit = log_fit(ranges, pos_sd)
    range_fit = log_fit(ranges, range_sd)
    S = signal_fit.constant  # eq. 6.10-6.12: intercept of log I_s against log z
    I_n = position_fit.constant * S  # eq. 6.14: intercept gives I_n/S
    T = range_fit.constant  # eq. 6.19
    fd = head.detector_length_m * I_n / (2.0 * T * S)  # eq. 6.20
    density = I_n / math.sqrt(head.bandwidth_hz)  # eq. 6.16, ideal filter

    sds = {}
    for name, angle in (
        ("centre", 0.0),
        ("left", head.scan_half_angle_rad),
        ("right", -head.scan_half_angle_rad),
    ):
        world = tilted_target_world(edge_range_m, angle)
        *_, rng_m = _stare_at(world, head, rng, calibration, angle, n_samples)
        sds[name] = float(np.nanstd(rng_m, ddof=1))
        if progress is not None:
            progress(ranges.size + len(sds), total)
    edge = {
        "range_m": edge_range_m,
        "sd_centre_m": sds["centre"],
        "sd_left_edge_m": sds["left"],
        "sd_right_edge_m": sds["right"],
        "left_ratio": sds["centre"] / sds["left"],
        "right_ratio": sds["centre"] / sds["right"],
        "ratio": sds["centre"] / (0.5 * (sds["left"] + sds["right"])),
        "cos3_theta": math.cos(head.scan_half_angle_rad) ** 3,
    }
    return CharacterisationResult(
        true_S_Am2=head.signal_constant_Am2,
        true_I_n_A=head.noise_current_A,
        true_fd_m2=head.fd_m2,
        ranges_m=ranges,
        mean_signal_A=mean_signal,
        position_sd=pos_sd,
        range_sd_m=range_sd,
        signal_fit=signal_fit,
        position_fit=position_fit,
        range_fit=range_fit,
        fit_S_Am2=S,
        fit_I_n_A=I_n,
        fit_T_per_m3=T,
        fit_fd_m2=fd,
        measured_density_A_per_rtHz=density,
        theoretical_density_A_per_rtHz=theoretical_noise_density(head),
        bandwidth_hz=head.bandwidth_hz,
        detector_length_m=head.detector_length_m,
        edge_accuracy=edge,
        histogram_range_m=1.0,
        histogram_samples_m=histogram,
    )
