"""Calibration: raw LEP samples to beam range with a per-sample standard deviation.

The calibration is a look-up table, as in the chapter (section 6.6.1, fig. 6.7; built from
planar targets by :mod:`agent.calibration.build`). The table holds *inverse* range on a
regular grid of scan angle and normalised image position, because inverse range is almost
linear in image position (exactly so on axis for an ideal head, eq. 6.5), which keeps
interpolation error far below the sensor's noise.

Every sample's standard deviation comes from its own intensity: ``σ_u = I_n / I_s``
(eq. 6.14) turned into range through the table's own gain ``|∂r/∂u|`` (the calibrated form
of eq. 6.6), so it includes the real head's ``fd``, baseline and LEP non-linearity.

A calibration is stored as a versioned ``.npz`` file with no pickled objects
(:meth:`Calibration.save`, :meth:`Calibration.load`); the package ships one made for the
default simulated head (:func:`load_default_calibration`). Before calibration the agent can
only use the nominal equations (:mod:`agent.calibration.nominal`).
"""

from __future__ import annotations

import io
import json
import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from agent.arrays import FloatArray
from agent.errors import CalibrationFileError
from agent.sensor.lep import position_from_currents, position_sigma
from agent.sensor.samples import CalibratedScan, RawSamples

CALIBRATION_FORMAT = "lep-range-calibration"
CALIBRATION_VERSION = 1
DEFAULT_CALIBRATION = "calibration_default.npz"
ANGLE_TOLERANCE_RAD = 1e-3  # ten times the mirror's 0.1 mrad repeatability


@dataclass(frozen=True)
class Calibration:
    """A range calibration: the look-up table plus the characterised sensor constants.

    Attributes
    ----------
    scan_angle_grid_rad : (nθ,) regular, ascending.
    position_grid : (nu,) regular, ascending normalised image positions.
    inverse_range_per_m : (nθ, nu) ``1/r`` at each node; NaN where the calibration did not
        reach (off the ends of the detector at that angle).
    signal_constant_Am2, noise_current_A, fd_m2 : characterised ``S``, ``I_n``, ``fd``.
    detection_delay_s : group delay of the detection filter.
    scan_rate_rad_s, scan_angle_sigma_rad : mirror rate, and its angle repeatability.
    metadata : how the table was made (free-form, JSON-serialisable).
    """

    scan_angle_grid_rad: FloatArray
    position_grid: FloatArray
    inverse_range_per_m: FloatArray
    signal_constant_Am2: float
    noise_current_A: float
    fd_m2: float
    detection_delay_s: float
    scan_rate_rad_s: float
    scan_angle_sigma_rad: float
    metadata: dict[str, Any] = field(default_factory=dict)
    _gradient: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        theta, u, q = self.scan_angle_grid_rad, self.position_grid, self.inverse_range_per_m
        if theta.ndim != 1 or u.ndim != 1 or q.shape != (theta.size, u.size):
            raise CalibrationFileError(
                None,
                f"table shape {q.shape} does not match its grids "
                f"({theta.size} angles, {u.size} positions)",
            )
        for name, grid in (("scan angle", theta), ("position", u)):
            steps = np.diff(grid)
            if (
                grid.size < 2
                or not np.allclose(steps, steps[0], rtol=1e-9, atol=1e-12)
                or steps[0] <= 0
            ):
                raise CalibrationFileError(None, f"{name} grid must be regular and ascending")
        for name in ("signal_constant_Am2", "noise_current_A", "fd_m2", "scan_rate_rad_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise CalibrationFileError(None, f"{name} must be positive, got {value}")
        # ∂(1/r)/∂u at every node, for the per-sample σ.
        object.__setattr__(self, "_gradient", np.gradient(q, u, axis=1))

    # ------------------------------------------------------------------------- conversion
    def lookup(
        self, scan_angle_rad: FloatArray, position_norm: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """Bilinear interpolation of ``1/r`` and ``∂(1/r)/∂u`` at the given samples.

        A hand-written bilinear look-up rather than scipy's RegularGridInterpolator: the
        table is regular, both quantities come from one index computation, and the call sits
        on every scan's hot path. Outside the grid, or next to an uncalibrated node: NaN.
        Scan angles up to ``ANGLE_TOLERANCE_RAD`` beyond the grid's ends (the mirror's
        repeatability at ±20°) take the end values.
        """
        theta = np.asarray(scan_angle_rad, dtype=np.float64)
        u = np.asarray(position_norm, dtype=np.float64)
        tg, ug = self.scan_angle_grid_rad, self.position_grid
        fi = (theta - tg[0]) / (tg[1] - tg[0])
        fj = (u - ug[0]) / (ug[1] - ug[0])
        slack = ANGLE_TOLERANCE_RAD / (tg[1] - tg[0])
        inside = (
            (fi >= -slack)
            & (fi <= tg.size - 1 + slack)
            & (fj >= -1e-9)
            & (fj <= ug.size - 1 + 1e-9)
        )
        fi = np.clip(np.nan_to_num(fi), 0.0, tg.size - 1)
        fj = np.clip(np.nan_to_num(fj), 0.0, ug.size - 1)
        i0 = np.minimum(fi.astype(np.intp), tg.size - 2)
        j0 = np.minimum(fj.astype(np.intp), ug.size - 2)
        a, b = fi - i0, fj - j0
        out = []
        for table in (self.inverse_range_per_m, self._gradient):
            value = (
                (1 - a) * (1 - b) * table[i0, j0]
                + (1 - a) * b * table[i0, j0 + 1]
                + a * (1 - b) * table[i0 + 1, j0]
                + a * b * table[i0 + 1, j0 + 1]
            )
            out.append(np.where(inside, value, np.nan))
        return out[0], out[1]

    def ranges(
        self, scan_angle_rad: FloatArray, position_norm: FloatArray, intensity_A: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """Beam range and its σ for each sample (eq. 6.14 through the calibrated gain).

        Returns ``(range_m, sigma_m)``, NaN where there is no reading.
        """
        q, dq = self.lookup(scan_angle_rad, position_norm)
        with np.errstate(divide="ignore", invalid="ignore"):
            valid = q > 0
            range_m = np.where(valid, 1.0 / q, np.nan)
            sigma_u = position_sigma(intensity_A, self.noise_current_A)
            sigma_m = np.where(valid, sigma_u * np.abs(dq) / q**2, np.nan)
        return range_m, sigma_m

    def beam_angles(self, raw: RawSamples) -> tuple[FloatArray, FloatArray]:
        """Times and scan angles the samples measure (see :func:`delay_corrected`)."""
        return delay_corrected(raw, self.detection_delay_s, self.scan_rate_rad_s)

    def calibrate_scan(self, raw: RawSamples) -> CalibratedScan:
        """Convert a raw scan to calibrated samples."""
        u, intensity = position_from_currents(raw.current_1_A, raw.current_2_A)
        time_s, theta = self.beam_angles(raw)
        range_m, sigma_m = self.ranges(theta, u, intensity)
        return CalibratedScan(
            time_s, theta, raw.pan_rad, u, intensity, range_m, sigma_m, raw.direction
        )

    # --------------------------------------------------------------------------- file I/O
    def save(self, path: str | Path) -> None:
        """Write the calibration as a versioned ``.npz`` file (no pickled objects)."""
        header = {
            "format": CALIBRATION_FORMAT,
            "version": CALIBRATION_VERSION,
            "signal_constant_Am2": self.signal_constant_Am2,
            "noise_current_A": self.noise_current_A,
            "fd_m2": self.fd_m2,
            "detection_delay_s": self.detection_delay_s,
            "scan_rate_rad_s": self.scan_rate_rad_s,
            "scan_angle_sigma_rad": self.scan_angle_sigma_rad,
            "metadata": self.metadata,
        }
        buffer = io.BytesIO()
        np.savez_compressed(
            buffer,
            header=np.frombuffer(json.dumps(header).encode(), dtype=np.uint8),
            scan_angle_grid_rad=self.scan_angle_grid_rad,
            position_grid=self.position_grid,
            inverse_range_per_m=self.inverse_range_per_m,
        )
        Path(path).write_bytes(buffer.getvalue())

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        """Read a calibration file; raise :class:`CalibrationFileError` if it is unusable."""
        try:
            data = Path(path).read_bytes()
        except OSError as exc:
            raise CalibrationFileError(path, f"cannot read: {exc.strerror or exc}") from None
        return cls.from_bytes(data, path)

    @classmethod
    def from_bytes(cls, data: bytes, path: str | Path | None = None) -> Calibration:
        try:
            with np.load(io.BytesIO(data), allow_pickle=False) as npz:
                arrays = {k: np.array(npz[k]) for k in npz.files}
        except Exception as exc:  # numpy raises many kinds for a damaged or foreign file
            raise CalibrationFileError(path, f"not a calibration file ({exc})") from None
        try:
            header = json.loads(bytes(arrays["header"]).decode())
        except Exception:
            raise CalibrationFileError(path, "missing or unreadable header") from None
        if not isinstance(header, dict) or header.get("format") != CALIBRATION_FORMAT:
            raise CalibrationFileError(path, f"not a {CALIBRATION_FORMAT} file")
        if header.get("version") != CALIBRATION_VERSION:
            raise CalibrationFileError(
                path,
                f"format version {header.get('version')!r} is not supported "
                f"(this program reads version {CALIBRATION_VERSION})",
            )
        try:
            cal = cls(
                scan_angle_grid_rad=arrays["scan_angle_grid_rad"].astype(np.float64),
                position_grid=arrays["position_grid"].astype(np.float64),
                inverse_range_per_m=arrays["inverse_range_per_m"].astype(np.float64),
                signal_constant_Am2=float(header["signal_constant_Am2"]),
                noise_current_A=float(header["noise_current_A"]),
                fd_m2=float(header["fd_m2"]),
                detection_delay_s=float(header["detection_delay_s"]),
                scan_rate_rad_s=float(header["scan_rate_rad_s"]),
                scan_angle_sigma_rad=float(header["scan_angle_sigma_rad"]),
                metadata=dict(header.get("metadata", {})),
            )
        except KeyError as exc:
            raise CalibrationFileError(path, f"missing entry {exc.args[0]!r}") from None
        except CalibrationFileError as exc:
            raise CalibrationFileError(path, exc.problem) from None
        except (TypeError, ValueError) as exc:
            raise CalibrationFileError(path, f"bad value: {exc}") from None
        return cal


def delay_corrected(
    raw: RawSamples, delay_s: float, scan_rate_rad_s: float, sample_rate_hz: float = 2560.0
) -> tuple[FloatArray, FloatArray]:
    """Times and scan angles the samples measure: ADC time and mirror angle less the delay.

    A sample taken at ``t`` saw the beam where the mirror pointed at ``t − delay`` (the
    detection filter's group delay). Just after a turnaround the mirror was still on its way
    in, so the angle folds back about the turning point, half a sample period before the
    first sample.
    """
    theta = raw.mirror_angle_rad - raw.direction * scan_rate_rad_s * delay_s
    if raw.direction != 0 and raw.time_s.size > 1:
        half_step = 0.5 * scan_rate_rad_s / sample_rate_hz
        turn = raw.mirror_angle_rad[0] - raw.direction * half_step
        before = raw.direction * (theta - turn) < 0
        theta = np.where(before, 2.0 * turn - theta, theta)
    return raw.time_s - delay_s, theta


def load_default_calibration() -> Calibration:
    """The calibration shipped with the package, made for the default simulated head."""
    ref = resources.files("agent.calibration") / "data" / DEFAULT_CALIBRATION
    return Calibration.from_bytes(ref.read_bytes(), str(ref))
