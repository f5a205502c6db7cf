"""The chapter's calibration and characterisation procedures, run against the simulated head.

* :func:`scan_calibration_planes` records fig. 6.7's data: planar targets at known distances
  across and beyond the depth of field, each swept many times in both directions.
* :func:`run_calibration` builds the look-up table from them, then characterises the sensor
  with it (``S``, ``I_n``, ``fd``) and stores those constants with the table.
* :func:`evaluate_calibration` measures range error before calibration (nominal equations) and
  after, over a grid of ranges and scan angles, in millimetres and in predicted σ.
* :func:`characterise` is section 6.6: a cardboard target on axis at 0.75-2.5 m, N stares at
  each range, least squares on logarithmic plots for ``S`` (eq. 6.10), ``I_n`` (eq. 6.14) and
  ``T`` hence ``fd`` (eq. 6.19-6.20); noise density against its theoretical value
  (eq. 6.16-6.18); Table 1; and the accuracy at the ±20° scan edges relative to the centre.

Targets are placed in a head-centred world: the vehicle stands so that the centre of scanning
is at the origin, looking along +x.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import stats

from agent.arrays import FloatArray
from agent.calibration.table import (
    Calibration,
    PlaneObservations,
    TableSettings,
    calibration_from_observations,
    delay_corrected,
    nominal_ranges,
)
from agent.kinematics.trajectory import StaticPose
from agent.sensor.detection import detection_delay_s
from agent.sensor.lep import position_from_currents
from agent.sensor.params import SensorParameters, nominal_sensor, theoretical_noise_density
from agent.sim.simulator import SensorSimulator
from agent.sim.world import World

# Table 1 of the chapter: range (m) and standard deviation of range (cm).
PAPER_TABLE_1: tuple[tuple[float, float], ...] = (
    (0.75, 0.05), (1.0, 0.148), (1.25, 0.463), (1.5, 0.798),
    (1.75, 1.568), (2.0, 2.547), (2.25, 3.713), (2.5, 7.662),
)  # fmt: skip
CHARACTERISATION_RANGES_M: tuple[float, ...] = tuple(r for r, _ in PAPER_TABLE_1)

Progress = Callable[[int, int], None]  # (done, total) callback for a progress bar


def head_centred_pose(params: SensorParameters) -> StaticPose:
    """Vehicle pose that puts the centre of scanning at the world origin, facing +x."""
    return StaticPose(-params.mount_offset_m, 0.0, 0.0)


def plane_world(
    distance_m: float, half_width_m: float | None = None, reflectivity: float = 1.0
) -> World:
    """A planar cardboard target perpendicular to +x at ``distance_m`` from the origin."""
    half = half_width_m if half_width_m is not None else distance_m * math.tan(0.5) + 0.5
    return World.build(walls=[(((distance_m, -half), (distance_m, half)), reflectivity)])


def tilted_target_world(
    range_m: float, scan_angle_rad: float, half_width_m: float = 0.3, reflectivity: float = 1.0
) -> World:
    """A target at beam range ``range_m`` along scan angle θ, facing along -x like a wall ahead."""
    cx, cy = range_m * math.cos(scan_angle_rad), range_m * math.sin(scan_angle_rad)
    return World.build(walls=[(((cx, cy - half_width_m), (cx, cy + half_width_m)), reflectivity)])


def arc_world(range_m: float, reflectivity: float = 1.0) -> World:
    """A concave circular target centred on the centre of scanning: every beam has range r."""
    return World.build(cylinders=[((0.0, 0.0), range_m, reflectivity)])


# ------------------------------------------------------------------------------- calibration
def calibration_plane_distances(
    n_planes: int = 48, near_m: float = 0.30, far_m: float = 3.45
) -> FloatArray:
    """Target distances spaced evenly in inverse distance (so evenly on the detector).

    They reach past both ends of the detector at every scan angle, so the table covers all of it.
    """
    return 1.0 / np.linspace(1.0 / far_m, 1.0 / near_m, n_planes)


def scan_calibration_planes(
    head: SensorParameters,
    rng: np.random.Generator,
    distances_m: Sequence[float] | FloatArray,
    n_sweeps: int,
    nominal: SensorParameters | None = None,
    progress: Progress | None = None,
) -> list[PlaneObservations]:
    """Sweep the full window ``n_sweeps`` times (alternating direction) over each plane.

    Angles and times are corrected for the detection delay with the nominal filter design
    (as the calibration stage does), so the table is indexed by the angle a sample measures.
    """
    nominal = nominal if nominal is not None else nominal_sensor()
    pose = head_centred_pose(head)
    delay = detection_delay_s(nominal)
    out = []
    for i, z in enumerate(distances_m):
        sim = SensorSimulator(plane_world(float(z)), head, rng)
        thetas, us, signals = [], [], []
        for s in range(n_sweeps):
            raw, _ = sim.sweep(
                direction=1 if s % 2 == 0 else -1,
                trajectory=pose,
                start_time_s=s * head.sweep_period_s,
            )
            u, intensity = position_from_currents(raw.current_1_A, raw.current_2_A)
            _, theta = delay_corrected(raw, delay, nominal.scan_rate_rad_s)
            thetas.append(theta)
            us.append(u)
            signals.append(intensity)
        out.append(
            PlaneObservations(
                float(z), np.concatenate(thetas), np.concatenate(us), np.concatenate(signals)
            )
        )
        if progress is not None:
            progress(i + 1, len(distances_m))
    return out


@dataclass(frozen=True)
class CalibrationSettings:
    """Sizes of the calibration run."""

    n_planes: int = 48
    n_sweeps: int = 32
    table: TableSettings = field(default_factory=TableSettings)
    characterisation_samples: int = 1000


def run_calibration(
    head: SensorParameters,
    rng: np.random.Generator,
    settings: CalibrationSettings | None = None,
    progress: Progress | None = None,
) -> tuple[Calibration, CharacterisationResult]:
    """Calibrate the head: plane scans to a look-up table, then characterise ``S, I_n, fd``."""
    settings = settings if settings is not None else CalibrationSettings()
    nominal = nominal_sensor()
    distances = calibration_plane_distances(settings.n_planes)
    planes = scan_calibration_planes(head, rng, distances, settings.n_sweeps, nominal, progress)
    metadata: dict[str, Any] = {
        "planes_m": [round(float(z), 6) for z in distances],
        "sweeps_per_plane": settings.n_sweeps,
        "curve_degree": settings.table.curve_degree,
    }
    # Build the table once; the constants come from characterising with it.
    provisional = calibration_from_observations(
        planes,
        signal_constant_Am2=nominal.signal_constant_Am2,
        noise_current_A=nominal.noise_current_A,
        fd_m2=nominal.fd_m2,
        nominal=nominal,
        settings=settings.table,
        metadata=metadata,
    )
    result = characterise(provisional, head, rng, settings.characterisation_samples)
    final = replace(
        provisional,
        signal_constant_Am2=result.fit_S_Am2,
        noise_current_A=result.fit_I_n_A,
        fd_m2=result.fit_fd_m2,
    )
    return final, result


# ------------------------------------------------------------------------ calibration error
@dataclass(frozen=True)
class ErrorGrid:
    """Range error statistics over a grid of ranges (rows) and scan-angle bins (columns)."""

    ranges_m: FloatArray
    angle_bin_edges_rad: FloatArray
    bias_mm: FloatArray
    rms_mm: FloatArray
    bias_sigma: FloatArray  # mean of (range − truth)/σ per cell
    rms_sigma: FloatArray
    count: np.ndarray

    def as_dict(self) -> dict[str, Any]:
        return {
            "ranges_m": self.ranges_m.tolist(),
            "angle_bin_edges_deg": np.degrees(self.angle_bin_edges_rad).round(3).tolist(),
            "bias_mm": self.bias_mm.round(4).tolist(),
            "rms_mm": self.rms_mm.round(4).tolist(),
            "bias_sigma": self.bias_sigma.round(4).tolist(),
            "rms_sigma": self.rms_sigma.round(4).tolist(),
            "max_abs_bias_sigma": float(np.nanmax(np.abs(self.bias_sigma))),
            "max_abs_bias_mm": float(np.nanmax(np.abs(self.bias_mm))),
        }


def _error_grid(
    ranges: FloatArray,
    edges: FloatArray,
    r_idx: np.ndarray,
    theta: FloatArray,
    err: FloatArray,
    sigma: FloatArray,
) -> ErrorGrid:
    shape = (ranges.size, edges.size - 1)
    bias, rms, zb, zr = (np.full(shape, np.nan) for _ in range(4))
    count = np.zeros(shape, dtype=np.int64)
    a_idx = np.clip(np.searchsorted(edges, theta, side="right") - 1, 0, edges.size - 2)
    ok = np.isfinite(err) & np.isfinite(sigma) & (sigma > 0)
    for i in range(shape[0]):
        for j in range(shape[1]):
            m = ok & (r_idx == i) & (a_idx == j)
            count[i, j] = np.count_nonzero(m)
            if count[i, j] > 1:
                bias[i, j] = 1e3 * np.mean(err[m])
                rms[i, j] = 1e3 * np.sqrt(np.mean(err[m] ** 2))
                zb[i, j] = np.mean(err[m] / sigma[m])
                zr[i, j] = np.sqrt(np.mean((err[m] / sigma[m]) ** 2))
    return ErrorGrid(ranges, edges, bias, rms, zb, zr, count)


def evaluate_calibration(
    calibration: Calibration,
    head: SensorParameters,
    rng: np.random.Generator,
    ranges_m: Sequence[float] = (0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.25, 2.5),
    n_angle_bins: int = 9,
    n_sweeps: int = 100,
    progress: Progress | None = None,
) -> tuple[ErrorGrid, ErrorGrid]:
    """Range error after and before calibration: ``(calibrated, nominal)`` grids.

    Each range is a concave circular target centred on the centre of scanning, so every beam
    meets it at exactly that range; samples are binned by scan angle. Both sweep directions.
    """
    nominal = nominal_sensor()
    pose = head_centred_pose(head)
    ranges = np.asarray(ranges_m, dtype=np.float64)
    edges = np.linspace(-head.scan_half_angle_rad, head.scan_half_angle_rad, n_angle_bins + 1)
    cols: dict[str, list[FloatArray]] = {
        k: [] for k in ("r", "theta", "cal", "cal_s", "nom", "nom_s")
    }
    for i, r in enumerate(ranges):
        sim = SensorSimulator(arc_world(float(r)), head, rng)
        for s in range(n_sweeps):
            raw, truth = sim.sweep(
                direction=1 if s % 2 == 0 else -1,
                trajectory=pose,
                start_time_s=s * head.sweep_period_s,
            )
            scan = calibration.calibrate_scan(raw)
            nom_r, nom_s = nominal_ranges(
                scan.scan_angle_rad, scan.image_position_norm, scan.intensity_A, nominal
            )
            cols["r"].append(np.full(len(raw), i))
            cols["theta"].append(scan.scan_angle_rad)
            cols["cal"].append(scan.range_m - truth.range_m)
            cols["cal_s"].append(scan.sigma_m)
            cols["nom"].append(nom_r - truth.range_m)
            cols["nom_s"].append(nom_s)
        if progress is not None:
            progress(i + 1, ranges.size)
    c = {k: np.concatenate(v) for k, v in cols.items()}
    r_idx = c["r"].astype(np.int64)
    return (
        _error_grid(ranges, edges, r_idx, c["theta"], c["cal"], c["cal_s"]),
        _error_grid(ranges, edges, r_idx, c["theta"], c["nom"], c["nom_s"]),
    )


# --------------------------------------------------------------------------- characterisation
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
