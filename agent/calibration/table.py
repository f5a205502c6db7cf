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

A file is judged before anything large is allocated: its size (:data:`MAX_CALIBRATION_FILE_BYTES`),
its zip directory (the format's four entries, stored or deflated), then each member's ``.npy``
header (dtype, shape within :data:`MAX_GRID_NODES`, C order) against the size the archive
declares for it; only then are the arrays read. A calibration's values, from a file or not,
must be plausible for this sensor: finite grids within ±45° and ±1, a table with at least one
calibrated node and every one within 0.2-5 m (NaN marks the nodes the calibration did not
reach), and constants within the stated factors of the nominal sensor's
(``_CONSTANT_BOUNDS``). Every refusal is one :class:`~agent.errors.CalibrationFileError` line.
"""

from __future__ import annotations

import functools
import io
import json
import math
import struct
import zipfile
import zlib
from dataclasses import dataclass, field
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from agent.arrays import FloatArray
from agent.calibration.lookup import BilinearTables
from agent.errors import CalibrationFileError
from agent.sensor.detection import detection_delay_s
from agent.sensor.lep import position_from_currents, position_sigma
from agent.sensor.params import SensorParameters
from agent.sensor.samples import CalibratedScan, RawSamples
from agent.toml_files import read_limited

CALIBRATION_FORMAT = "lep-range-calibration"
CALIBRATION_VERSION = 1
DEFAULT_CALIBRATION = "calibration_default.npz"
ANGLE_TOLERANCE_RAD = 1e-3  # ten times the mirror's 0.1 mrad repeatability

# Limits on a calibration file, checked before anything large is read or allocated.
MAX_GRID_NODES = 2048
"""Most nodes in either grid. The shipped table has 161 × 201 nodes and its interpolation error
is already far below the sensor's noise; 2048 is ten times finer or more in each (8 nodes per
sample spacing in angle) and keeps a table within 32 MiB."""
MAX_HEADER_BYTES = 64 * 1024
"""Longest JSON header (constants and metadata): the shipped one is under 1 kB."""
MAX_CALIBRATION_FILE_BYTES = 33 * 1024 * 1024
"""Largest calibration file: a table at the grid limits stored uncompressed (32 MiB), its grids
(32 kB), its header and the zip archive's own records fit well within it."""
_MAX_ZIP_DIRECTORY_BYTES = 4096
"""Largest zip central directory: four entries of well under 200 bytes each."""

# Plausibility of a calibration's values. Ranges: the table may reach a little beyond the
# 0.4-2.5 m depth of field (the shipped one covers 0.33-3.0 m), so a factor of two either way.
# Anything outside is a table in other units (mm, cm) or for another sensor.
MIN_INVERSE_RANGE_PER_M = 1.0 / 5.0
MAX_INVERSE_RANGE_PER_M = 1.0 / 0.2
MAX_SCAN_ANGLE_RAD = math.pi / 4
"""The grids' scan angles lie within ±45°: a head's half-angle must be below 45° (the mirror
sweeps ±20°); beyond, the geometry of eq. 6.5 has no image."""
_NOMINAL = SensorParameters()
_CONSTANT_BOUNDS: dict[str, tuple[float, float, str]] = {
    # name: (low, high, why), from the nominal sensor (agent.sensor.params)
    "signal_constant_Am2": (
        _NOMINAL.signal_constant_Am2 / 10,
        _NOMINAL.signal_constant_Am2 * 10,
        "a tenth to ten times the nominal sensor's: S follows laser power and aperture",
    ),
    "noise_current_A": (
        _NOMINAL.noise_current_A / 10,
        _NOMINAL.noise_current_A * 10,
        "a tenth to ten times the nominal sensor's 36.5 pA over its 1 kHz bandwidth",
    ),
    "fd_m2": (
        _NOMINAL.fd_m2 / 2,
        _NOMINAL.fd_m2 * 2,
        "half to twice the head's f·d = 0.00475 m²; characterisation moves it by percents",
    ),
    "detection_delay_s": (
        0.0,
        10 * detection_delay_s(_NOMINAL),
        "up to ten times the nominal 4th-order 1 kHz Bessel filter's 0.34 ms; an 8th-order "
        "one delays 0.51 ms",
    ),
    "scan_rate_rad_s": (
        _NOMINAL.scan_rate_rad_s / 10,
        _NOMINAL.scan_rate_rad_s * 10,
        "a tenth to ten times the nominal 40° per 100 ms",
    ),
    "scan_angle_sigma_rad": (
        0.0,
        ANGLE_TOLERANCE_RAD,
        "up to ten times the mirror's 0.1 mrad repeatability, the look-up's tolerance",
    ),
}


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
        _check_table(theta, u, q)
        _check_constants(self)
        # ∂(1/r)/∂u at every node, for the per-sample σ.
        object.__setattr__(self, "_gradient", np.gradient(q, u, axis=1))

    # ------------------------------------------------------------------------- conversion
    @cached_property
    def _tables(self) -> BilinearTables:
        """Both tables, stacked for the look-up (made on the first one)."""
        tg = self.scan_angle_grid_rad
        slack = ANGLE_TOLERANCE_RAD / (tg[1] - tg[0])
        return BilinearTables(
            tg, self.position_grid, self.inverse_range_per_m, self._gradient, slack
        )

    def lookup(
        self, scan_angle_rad: FloatArray, position_norm: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """Bilinear interpolation of ``1/r`` and ``∂(1/r)/∂u`` at the given samples.

        A hand-written bilinear look-up rather than scipy's RegularGridInterpolator: the
        table is regular, both quantities come from one index computation, and the call sits
        on every scan's hot path (see :mod:`agent.calibration.lookup`). Outside the grid, or
        next to an uncalibrated node: NaN. Scan angles up to ``ANGLE_TOLERANCE_RAD`` beyond
        the grid's ends (the mirror's repeatability at ±20°) take the end values.
        """
        theta = np.asarray(scan_angle_rad, dtype=np.float64)
        u = np.asarray(position_norm, dtype=np.float64)
        values, inside = self._tables.interpolate(theta, u)
        out = np.where(inside, values, np.nan)
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
        header_bytes = json.dumps(header).encode()
        if len(header_bytes) > MAX_HEADER_BYTES:
            raise CalibrationFileError(
                path,
                f"header of {len(header_bytes)} bytes is larger than the {MAX_HEADER_BYTES}-byte "
                "limit (is the metadata too large?)",
            )
        buffer = io.BytesIO()
        np.savez_compressed(  # C order, float64: the only layout load accepts
            buffer,
            header=np.frombuffer(header_bytes, dtype=np.uint8),
            scan_angle_grid_rad=np.ascontiguousarray(self.scan_angle_grid_rad, np.float64),
            position_grid=np.ascontiguousarray(self.position_grid, np.float64),
            inverse_range_per_m=np.ascontiguousarray(self.inverse_range_per_m, np.float64),
        )
        Path(path).write_bytes(buffer.getvalue())

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        """Read a calibration file; raise :class:`CalibrationFileError` if it is unusable.

        The file's size is checked before it is read (:data:`MAX_CALIBRATION_FILE_BYTES`).
        """
        data = read_limited(
            path,
            functools.partial(CalibrationFileError, path),
            max_bytes=MAX_CALIBRATION_FILE_BYTES,
        )
        return cls.from_bytes(data, path)

    @classmethod
    def from_bytes(cls, data: bytes, path: str | Path | None = None) -> Calibration:
        """A calibration from a file's bytes; ``path`` names it in errors.

        Every member's zip record and ``.npy`` header is checked against the format and its
        limits before any array is read, so a small file claiming a huge table costs nothing;
        then the values are checked (see :class:`Calibration`).
        """
        arrays = _read_arrays(data, path)
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
        except (TypeError, ValueError, OverflowError) as exc:
            raise CalibrationFileError(path, f"bad value: {exc}") from None
        return cal


_MEMBERS = ("header", "scan_angle_grid_rad", "position_grid", "inverse_range_per_m")
"""The arrays of a calibration file, each stored as ``<name>.npy``, in the order checked."""
_ZIP_END = struct.Struct("<4s4H2LH")
"""A zip archive's end record: signature, disk numbers, entries on this disk, entries,
central directory size and offset, comment length."""


def _zip_directory(data: bytes) -> tuple[int, int] | None:
    """(entries, central directory bytes) from a zip archive's end record, or ``None``.

    Found the way :mod:`zipfile` finds it (the last 22 bytes, else the last signature within
    the 64 KiB a comment may take), so the counts are those :class:`zipfile.ZipFile` will
    read, and the directory can be judged before it is parsed.
    """
    size = _ZIP_END.size
    if data[-size : -size + 4] == b"PK\x05\x06" and data[-2:] == b"\0\0":
        start = len(data) - size
    else:
        start = data.rfind(b"PK\x05\x06", max(len(data) - size - 0xFFFF, 0))
        if start < 0 or len(data) - start < size:
            return None
    fields = _ZIP_END.unpack_from(data, start)
    return int(fields[4]), int(fields[5])


def _check_members(archive: zipfile.ZipFile, path: str | Path | None) -> None:
    """Refuse an archive whose members are not the format's, judged by their headers alone.

    Each member's zip record and ``.npy`` header (dtype, shape, order) are read, a few hundred
    bytes, and the member's declared size is compared with what its header describes, so no
    array is allocated before its shape and size are known to be within the limits.
    """

    def fail(problem: str) -> NoReturn:
        raise CalibrationFileError(path, problem)

    names = [info.filename for info in archive.infolist()]
    if len(set(names)) != len(names):
        fail("an entry appears twice in the archive")
    for name in names:
        if name.removesuffix(".npy") not in _MEMBERS or not name.endswith(".npy"):
            fail(f"unexpected entry {name!r}")
    shapes: dict[str, tuple[int, ...]] = {}
    for member in _MEMBERS:
        if member + ".npy" not in names:
            fail(f"missing entry {member!r}")
        info = archive.getinfo(member + ".npy")
        if info.flag_bits & 0x1:
            fail(f"{member}: encrypted")
        if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
            fail(f"{member}: zip compression method {info.compress_type} (stored or deflated only)")
        with archive.open(info) as f:
            version = np.lib.format.read_magic(f)
            if version == (1, 0):
                shape, fortran_order, dtype = np.lib.format.read_array_header_1_0(f)
            elif version == (2, 0):
                shape, fortran_order, dtype = np.lib.format.read_array_header_2_0(f)
            else:
                fail(f"{member}: .npy format version {version[0]}.{version[1]} (1.0 or 2.0 only)")
            header_bytes = f.tell()
        if member == "header":
            wanted, limit = f"uint8 of 1 to {MAX_HEADER_BYTES} bytes", MAX_HEADER_BYTES
            dtype_ok = dtype == np.dtype(np.uint8)
            shape_ok = len(shape) == 1 and 1 <= shape[0] <= limit
        elif member == "inverse_range_per_m":
            n_angles, n_positions = shapes["scan_angle_grid_rad"][0], shapes["position_grid"][0]
            wanted = f"float64 of shape ({n_angles}, {n_positions}), as its grids"
            dtype_ok = dtype.kind == "f" and dtype.itemsize == 8
            shape_ok = shape == (n_angles, n_positions)
        else:
            wanted = f"float64 of 2 to {MAX_GRID_NODES} nodes"
            dtype_ok = dtype.kind == "f" and dtype.itemsize == 8
            shape_ok = len(shape) == 1 and 2 <= shape[0] <= MAX_GRID_NODES
        if not (dtype_ok and shape_ok):
            fail(f"{member}: {dtype} of shape {shape}; the format has {wanted}")
        if fortran_order:
            fail(f"{member}: stored in Fortran order (the format stores C order)")
        needed = header_bytes + math.prod(shape) * dtype.itemsize
        if info.file_size != needed:
            fail(
                f"{member}: the archive declares {info.file_size} bytes where its .npy header "
                f"describes {needed}"
            )
        shapes[member] = shape


def _read_arrays(data: bytes, path: str | Path | None) -> dict[str, np.ndarray[Any, Any]]:
    """The arrays of a calibration file, each checked (:func:`_check_members`) before read."""
    if len(data) > MAX_CALIBRATION_FILE_BYTES:
        raise CalibrationFileError(
            path, f"larger than the {MAX_CALIBRATION_FILE_BYTES}-byte limit ({len(data)} bytes)"
        )
    directory = _zip_directory(data)
    if directory is None:
        raise CalibrationFileError(path, "not a calibration file (not a zip archive)")
    entries, directory_bytes = directory
    if entries > len(_MEMBERS) or directory_bytes > _MAX_ZIP_DIRECTORY_BYTES:
        raise CalibrationFileError(
            path,
            f"not a calibration file (its zip directory lists {entries} entries in "
            f"{directory_bytes} bytes; the format has {len(_MEMBERS)})",
        )
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            _check_members(archive, path)
            arrays = {}
            for member in _MEMBERS:
                with archive.open(member + ".npy") as f:
                    arrays[member] = np.lib.format.read_array(f, allow_pickle=False)
    except CalibrationFileError:
        raise
    except (
        zipfile.BadZipFile,
        zlib.error,
        EOFError,
        OSError,
        ValueError,  # a damaged .npy header
        SyntaxError,  # likewise, from numpy's parsing of it
        RecursionError,
        MemoryError,
        NotImplementedError,
        RuntimeError,
    ) as exc:
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise CalibrationFileError(path, f"not a calibration file ({reason})") from None
    return arrays


def _check_table(theta: FloatArray, u: FloatArray, q: FloatArray) -> None:
    """Refuse grids and a table the look-up cannot use or no sensor of this kind could make."""

    def fail(problem: str) -> NoReturn:
        raise CalibrationFileError(None, problem)

    if theta.ndim != 1 or u.ndim != 1 or q.shape != (theta.size, u.size):
        fail(
            f"table shape {q.shape} does not match its grids "
            f"({theta.size} angles, {u.size} positions)"
        )
    for name, grid, limit, unit in (
        ("scan angle", theta, MAX_SCAN_ANGLE_RAD, "rad (±45°)"),
        ("position", u, 1.0, "(the ends of the detector)"),
    ):
        if not 2 <= grid.size <= MAX_GRID_NODES:
            fail(f"{name} grid has {grid.size} nodes (2 to {MAX_GRID_NODES} are allowed)")
        if not np.all(np.isfinite(grid)):
            fail(f"{name} grid holds NaN or infinite values")
        steps = np.diff(grid)
        if not np.allclose(steps, steps[0], rtol=1e-9, atol=1e-12) or steps[0] <= 0:
            fail(f"{name} grid must be regular and ascending")
        if grid[0] < -limit or grid[-1] > limit:
            fail(
                f"{name} grid must lie within ±{limit:g} {unit}, "
                f"got {grid[0]:.6g} to {grid[-1]:.6g}"
            )
    if np.any(np.isinf(q)):
        fail("inverse_range_per_m holds infinite values (NaN marks uncalibrated nodes)")
    calibrated = q[np.isfinite(q)]
    if calibrated.size == 0:
        fail("inverse_range_per_m has no calibrated (finite) value")
    low, high = float(calibrated.min()), float(calibrated.max())
    if low < MIN_INVERSE_RANGE_PER_M or high > MAX_INVERSE_RANGE_PER_M:
        fail(
            f"inverse_range_per_m must be from {MIN_INVERSE_RANGE_PER_M:g} to "
            f"{MAX_INVERSE_RANGE_PER_M:g} per metre where calibrated (ranges of "
            f"{1 / MAX_INVERSE_RANGE_PER_M:g} to {1 / MIN_INVERSE_RANGE_PER_M:g} m, the "
            f"0.4-2.5 m depth of field with a factor of two to spare), got {low:.6g} to {high:.6g}"
        )


def _check_constants(cal: Calibration) -> None:
    """Refuse characterised constants outside :data:`_CONSTANT_BOUNDS`."""
    for name, (low, high, why) in _CONSTANT_BOUNDS.items():
        value = getattr(cal, name)
        if not (isinstance(value, int | float) and math.isfinite(value) and low <= value <= high):
            raise CalibrationFileError(
                None, f"{name} must be from {low:.4g} to {high:.4g} ({why}), got {value!r}"
            )


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
