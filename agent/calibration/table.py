"""Calibration: raw LEP samples to beam range with a per-sample standard deviation.

The calibration is a look-up table, as in the chapter (section 6.6.1, fig. 6.7): planar
targets at known distances are scanned across the whole field of view; for every scan angle
the recorded image positions of the targets, paired with their known ranges, give range as a
function of image position. The table holds *inverse* range on a regular grid of scan angle
and normalised image position, because inverse range is almost linear in image position
(exactly so on axis for an ideal head, eq. 6.5), which keeps interpolation error far below
the sensor's noise.

Every sample's standard deviation comes from its own intensity: ``σ_u = I_n / I_s``
(eq. 6.14) turned into range through the table's own gain ``|∂r/∂u|`` (the calibrated form
of eq. 6.6), so it includes the real head's ``fd``, baseline and LEP non-linearity.

Before calibration the agent can only use the nominal equations (:func:`nominal_ranges`):
``fd = f·d``, the drawn detector position, a linear LEP.
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
from numpy.polynomial import Chebyshev

from agent.arrays import FloatArray
from agent.errors import CalibrationFileError
from agent.sensor.lep import image_position, position_from_currents, position_sigma
from agent.sensor.params import SensorParameters, nominal_sensor
from agent.sensor.samples import CalibratedScan, RawSamples
from agent.sensor.triangulation import synchronised_range, synchronised_range_gain

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


def nominal_ranges(
    scan_angle_rad: FloatArray,
    position_norm: FloatArray,
    intensity_A: FloatArray,
    params: SensorParameters | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Range and σ from the nominal equations alone: what the agent has before calibration.

    ``r = (fd/p)·cos θ + d·sin θ`` (eq. 6.5) with the drawn ``fd = f·d`` and detector offset.
    """
    params = params if params is not None else nominal_sensor()
    p = image_position(position_norm, params)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = synchronised_range(p, scan_angle_rad, params.fd_m2, params.baseline_m)
        gain = synchronised_range_gain(r, scan_angle_rad, params.fd_m2, params.baseline_m)
        sigma_p = (
            position_sigma(intensity_A, params.noise_current_A) * 0.5 * params.detector_length_m
        )
        sigma = sigma_p / gain
    return r, sigma


# ------------------------------------------------------------------------ building the table
@dataclass(frozen=True)
class PlaneObservations:
    """Calibrated-time samples of one planar target at a known perpendicular distance.

    The plane is perpendicular to the head's x axis at ``distance_m`` from the centre of
    scanning, so a beam at scan angle θ meets it at range ``distance_m / cos θ``.
    """

    distance_m: float
    scan_angle_rad: FloatArray
    position_norm: FloatArray
    intensity_A: FloatArray


@dataclass(frozen=True)
class TableSettings:
    """How finely the look-up table is tabulated and how the plane curves are smoothed.

    ``curve_degree``: Chebyshev degree of each plane's image position against scan angle
    (a smooth curve, fig. 6.7; fitting it averages thousands of samples per plane).
    ``max_extrapolation``: how far, in normalised position, the table may extend beyond the
    nearest and farthest planes seen at an angle (inverse range is nearly linear in position).
    ``max_angle_extrapolation_rad``: likewise in scan angle; the outermost samples of a full
    sweep sit half a sample spacing inside ±20°.
    ``min_snr``: samples whose signal is below this many noise currents are left out; where a
    plane images off the detector the electrodes carry only noise, and a noise-only sample can
    still fall inside [-1, 1].
    """

    n_scan_angles: int = 161
    n_positions: int = 201
    curve_degree: int = 8
    max_extrapolation: float = 0.05
    max_angle_extrapolation_rad: float = 0.005
    min_samples_per_plane: int = 64
    min_snr: float = 20.0


def fit_plane_curve(
    obs: PlaneObservations, settings: TableSettings, noise_current_A: float
) -> tuple[Chebyshev, float, float] | None:
    """Weighted Chebyshev fit of image position against scan angle for one plane.

    Weights are ``I_s`` (``1/σ_u`` up to a constant, eq. 6.14). Returns the curve and the
    angle interval it covers, or ``None`` if the plane gave too few readings.
    """
    ok = np.isfinite(obs.position_norm) & (obs.intensity_A > settings.min_snr * noise_current_A)
    if np.count_nonzero(ok) < settings.min_samples_per_plane:
        return None
    theta = obs.scan_angle_rad[ok]
    # A plane seen over only part of the scan (its image runs off the detector) gets a lower
    # degree, in proportion: a high-degree fit over a sliver of angle is unconstrained.
    full_span = 2.0 * float(np.max(np.abs(obs.scan_angle_rad)))
    span = float(theta.max() - theta.min())
    degree = max(1, min(settings.curve_degree, math.ceil(settings.curve_degree * span / full_span)))
    curve = Chebyshev.fit(theta, obs.position_norm[ok], degree, w=obs.intensity_A[ok])
    return curve, float(theta.min()), float(theta.max())


def build_table(
    observations: list[PlaneObservations],
    scan_half_angle_rad: float,
    noise_current_A: float,
    settings: TableSettings | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Build the inverse-range table from plane observations.

    Returns ``(scan_angle_grid, position_grid, inverse_range)``; see :class:`Calibration`.
    """
    # Imported here: the processes that only load and apply a calibration never build one,
    # and scipy would add about 0.5 s to each one's start (five start at once on two cores).
    from scipy.interpolate import CubicSpline

    settings = settings if settings is not None else TableSettings()
    theta_grid = np.linspace(-scan_half_angle_rad, scan_half_angle_rad, settings.n_scan_angles)
    u_grid = np.linspace(-1.0, 1.0, settings.n_positions)
    curves = []
    for obs in observations:
        fitted = fit_plane_curve(obs, settings, noise_current_A)
        if fitted is not None:
            curves.append((obs.distance_m, *fitted))
    if len(curves) < 4:
        raise ValueError(f"calibration needs readings from at least 4 planes, got {len(curves)}")
    table = np.full((theta_grid.size, u_grid.size), np.nan)
    for i, theta in enumerate(theta_grid):
        reach_rad = settings.max_angle_extrapolation_rad
        nodes = [
            (curve(theta), math.cos(theta) / z)
            for z, curve, lo, hi in curves
            if lo - reach_rad <= theta <= hi + reach_rad
        ]
        if len(nodes) < 4:
            continue
        u_k, q_k = np.array(sorted(nodes)).T
        if np.any(np.diff(u_k) <= 0) or np.any(np.diff(q_k) <= 0):
            raise ValueError(
                f"calibration curves cross at scan angle {math.degrees(theta):.2f}°"
                " (image position must fall monotonically with range)"
            )
        spline = CubicSpline(u_k, q_k, bc_type="natural")
        reach = (u_grid >= u_k[0] - settings.max_extrapolation) & (
            u_grid <= u_k[-1] + settings.max_extrapolation
        )
        table[i, reach] = spline(u_grid[reach])
    return theta_grid, u_grid, table


def calibration_from_observations(
    observations: list[PlaneObservations],
    *,
    signal_constant_Am2: float,
    noise_current_A: float,
    fd_m2: float,
    nominal: SensorParameters | None = None,
    settings: TableSettings | None = None,
    metadata: dict[str, Any] | None = None,
) -> Calibration:
    """A :class:`Calibration` from plane observations and characterised constants."""
    from agent.sensor.detection import detection_delay_s  # scipy.signal: see build_table

    nominal = nominal if nominal is not None else nominal_sensor()
    theta_grid, u_grid, table = build_table(
        observations, nominal.scan_half_angle_rad, noise_current_A, settings
    )
    return Calibration(
        scan_angle_grid_rad=theta_grid,
        position_grid=u_grid,
        inverse_range_per_m=table,
        signal_constant_Am2=signal_constant_Am2,
        noise_current_A=noise_current_A,
        fd_m2=fd_m2,
        detection_delay_s=detection_delay_s(nominal),
        scan_rate_rad_s=nominal.scan_rate_rad_s,
        scan_angle_sigma_rad=nominal.scan_angle_repeatability_rad,
        metadata=dict(metadata or {}),
    )
