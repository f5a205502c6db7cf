"""How much range error a calibration removes: before (nominal equations) and after.

:func:`evaluate_calibration` measures the range error over a grid of ranges and scan angles,
in millimetres and in predicted σ, with the calibration's look-up table and with the nominal
equations alone, against the simulation's truth.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from agent.arrays import FloatArray
from agent.calibration.nominal import nominal_ranges
from agent.calibration.progress import Progress
from agent.calibration.table import Calibration
from agent.sensor.params import SensorParameters, nominal_sensor
from agent.sim.simulator import SensorSimulator
from agent.sim.targets import arc_world, head_centred_pose


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
